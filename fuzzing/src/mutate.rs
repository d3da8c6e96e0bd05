//! A seeded mutator: small structural edits of real inputs, the way coverage-guided fuzzers
//! mutate, without needing their runtime (it runs under `cargo test` on stable Rust). The edits
//! are written here because they are specific to inputs that are text or little-endian binary
//! headers; the randomness is `rand`'s `SmallRng` from a fixed seed.

use rand::rngs::SmallRng;
use rand::RngExt;

/// Values that break size arithmetic and range checks, written as little-endian integers.
const INTERESTING: [u64; 10] = [
    0,
    1,
    0x7f,
    0xff,
    0xffff_ffff,
    0x8000_0000,
    1 << 32,
    0x7fff_ffff_ffff_ffff,
    u64::MAX,
    16_000_000_000,
];

/// One edit of `data`: a bit flip, an interesting byte, word or number written over it, a
/// number in text replaced whole by an interesting one, a dictionary token inserted or written
/// over it, a range deleted, duplicated or cut off, or a splice of `other`.
fn edit(rng: &mut SmallRng, data: &mut Vec<u8>, dictionary: &[&[u8]], other: &[u8]) {
    let at = |rng: &mut SmallRng, len: usize| {
        if len == 0 {
            0
        } else {
            rng.random_range(0..len)
        }
    };
    let len = data.len();
    match rng.random_range(0..11) {
        0 if len > 0 => {
            let i = at(rng, len);
            data[i] ^= 1 << rng.random_range(0..8);
        }
        1 if len > 0 => {
            let i = at(rng, len);
            data[i] = [0, 0xff, 0x7f, 0x80, b'\n', b'<', b'"', b'-'][rng.random_range(0..8)];
        }
        2 if len >= 8 => {
            let width = [4, 8][rng.random_range(0..2)];
            let i = at(rng, len - width + 1) & !(width - 1);
            let v = INTERESTING[rng.random_range(0..INTERESTING.len())].to_le_bytes();
            data[i..i + width].copy_from_slice(&v[..width]);
        }
        3 | 4 if !dictionary.is_empty() => {
            let token = dictionary[rng.random_range(0..dictionary.len())];
            let i = at(rng, len + 1);
            if rng.random_range(0..2) == 0 {
                data.splice(i..i, token.iter().copied());
            } else {
                let end = (i + token.len()).min(len);
                data.splice(i..end, token.iter().copied());
            }
        }
        5 if len > 0 => {
            let i = at(rng, len);
            let n = 1 + rng.random_range(0..(len - i).min(64));
            data.drain(i..i + n);
        }
        6 if len > 0 => {
            let i = at(rng, len);
            let n = 1 + rng.random_range(0..(len - i).min(256));
            let copy = data[i..i + n].to_vec();
            let j = at(rng, len + 1);
            data.splice(j..j, copy);
        }
        7 if len > 0 => data.truncate(at(rng, len)),
        8 if !other.is_empty() => {
            let i = at(rng, len + 1);
            let j = at(rng, other.len());
            data.truncate(i);
            data.extend_from_slice(&other[j..]);
        }
        9 if len > 0 => {
            // The next run of digits from a random place, so that text formats get the values
            // binary headers get: a value, not a token inserted beside one.
            let i = at(rng, len);
            if let Some(start) = data[i..].iter().position(u8::is_ascii_digit).map(|k| i + k) {
                let end = data[start..]
                    .iter()
                    .position(|b| !b.is_ascii_digit())
                    .map_or(len, |k| start + k);
                let v = INTERESTING[rng.random_range(0..INTERESTING.len())].to_string();
                data.splice(start..end, v.bytes());
            }
        }
        _ => {
            let i = at(rng, len + 1);
            let digit = b"0123456789.e-+"[rng.random_range(0..14)];
            data.insert(i, digit);
        }
    }
}

/// A mutant of `seed`: 1 to 8 edits (never longer than 1 MiB).
pub fn mutate(rng: &mut SmallRng, seed: &[u8], dictionary: &[&[u8]], other: &[u8]) -> Vec<u8> {
    let mut data = seed.to_vec();
    for _ in 0..1 + rng.random_range(0..8) {
        edit(rng, &mut data, dictionary, other);
    }
    data.truncate(1 << 20);
    data
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn the_same_seed_gives_the_same_mutants() {
        let run = |seed| {
            let mut rng = SmallRng::seed_from_u64(seed);
            (0..100)
                .map(|_| mutate(&mut rng, b"<osm>1.5 2.5</osm>", &[b"nan"], b"xyz"))
                .collect::<Vec<_>>()
        };
        assert_eq!(run(7), run(7));
        assert_ne!(run(7), run(8));
        assert!(run(7).iter().any(|m| m.windows(3).any(|w| w == b"nan")));
    }

    /// A number in text is replaced whole, its line otherwise kept: the mutant a manifest's
    /// overflowing cell length needed (docs/robustness.md).
    #[test]
    fn a_number_in_text_is_replaced_whole() {
        let mut rng = SmallRng::seed_from_u64(3);
        let whole = format!("x = 1\nbytes = {}\npoints = 9\n", u64::MAX);
        let found = (0..5000).any(|_| {
            let mut data = b"x = 1\nbytes = 4096\npoints = 9\n".to_vec();
            edit(&mut rng, &mut data, &[], b"");
            data == whole.as_bytes()
        });
        assert!(found);
    }
}
