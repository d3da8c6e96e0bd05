//! Numbers as the text the output files carry: the shortest decimal that reads back to the same
//! `f64`, written exactly as `format!("{}", v)` writes it, for a third of the instructions.
//!
//! A corrected KITTI trajectory is twelve numbers a pose and its status CSV ten more; with
//! `std`'s formatting these were 9 % of a whole `correct` run's instructions (docs/performance.md).
//! `zmij` finds the same shortest digits, but for two differences that are adapted here: the
//! spelling (`std` writes no `.0` after a whole number and never an exponent), and ties. When
//! two 17-digit decimals lie equally close to the value, `std` takes the larger digit and `zmij`
//! the even one; those values are told by their bits (`may_tie`) and left to `std`.

/// Appends `v` to `out` as `write!(out, "{v}")` would.
pub fn push_f64(out: &mut String, v: f64) {
    let mut buffer = zmij::Buffer::new();
    let text = buffer.format(v);
    if !v.is_finite() || text.contains('e') || may_tie(v) {
        // Non-finite values, those beyond 1e-5..1e16 (zmij's exponent form) and possible ties:
        // `std`'s own.
        use std::fmt::Write;
        let _ = write!(out, "{v}");
    } else {
        out.push_str(text.strip_suffix(".0").unwrap_or(text));
    }
}

/// Appends `values` to `out` as [`push_f64`] writes them, `separator` between them.
pub fn push_separated(out: &mut String, values: &[f64], separator: char) {
    for (i, &v) in values.iter().enumerate() {
        if i > 0 {
            out.push(separator);
        }
        push_f64(out, v);
    }
}

/// Whether two shortest decimals of `v` can be equally close to it. `v` is `m / 2^k` with `m`
/// odd, and its exact decimal has the digits of `m 5^k`; a tie between two 17-digit decimals
/// needs exactly 18 of them, so `m 5^k < 10^18`: `log2 m + k log2 5 < 59.8`. Computed values
/// (all 53 bits of mantissa in play) pass this only above about 10^14; whole numbers never tie.
fn may_tie(v: f64) -> bool {
    const MANTISSA_BITS: u32 = 52;
    let bits = v.to_bits();
    let biased_exponent = ((bits >> MANTISSA_BITS) & 0x7ff) as i32;
    let fraction = bits & ((1 << MANTISSA_BITS) - 1);
    let mantissa = if biased_exponent == 0 {
        fraction
    } else {
        fraction | (1 << MANTISSA_BITS)
    };
    if mantissa == 0 {
        return false;
    }
    let zeros = mantissa.trailing_zeros();
    let odd_bits = 64 - (mantissa >> zeros).leading_zeros();
    // v = mantissa 2^(e - 1075), e the biased exponent (1 for subnormals).
    let k = 1075 - biased_exponent.max(1) - zeros as i32;
    // log2 m < odd_bits, so the test below holds whenever m 5^k < 10^18 does.
    // log2 5 = log2 10 - 1.
    k > 0 && f64::from(odd_bits) - 1.0 + f64::from(k) * (std::f64::consts::LOG2_10 - 1.0) < 59.8
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn text(v: f64) -> String {
        let mut s = String::new();
        push_f64(&mut s, v);
        s
    }

    #[test]
    fn spells_numbers_as_std_does() {
        let cases = [
            0.0,
            -0.0,
            1.0,
            -3.0,
            0.1,
            1e-5,
            9.99e-6,
            1e-7,
            123456.789,
            1e15,
            1e16,
            1e22,
            f64::MAX,
            f64::MIN_POSITIVE,
            5e-324,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            0.30000000000000004,
            1.0 + 2f64.powi(-17),
            -1178526356161771.2,
            123456789012.03125,
        ];
        for v in cases {
            assert_eq!(text(v), format!("{v}"), "{v:?}");
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 20_000, rng_seed: proptest::test_runner::RngSeed::Fixed(15), ..ProptestConfig::default() })]

        /// Any bit pattern: every exponent, subnormals, non-finite values.
        #[test]
        fn any_f64_reads_as_std_writes_it(bits in any::<u64>()) {
            let v = f64::from_bits(bits);
            prop_assert_eq!(text(v), format!("{v}"));
        }

        /// Values with a short binary fraction, where ties are: `n / 2^k`.
        #[test]
        fn dyadic_values_read_as_std_writes_them(n in any::<i64>(), k in 0i32..64) {
            let v = n as f64 / 2f64.powi(k);
            prop_assert_eq!(text(v), format!("{v}"));
        }

        /// The values the files carry: poses in metres and radians, covariances.
        #[test]
        fn output_range_reads_as_std_writes_it(v in -1e5f64..1e5, scale in -12i32..6) {
            let v = v * 10f64.powi(scale);
            prop_assert_eq!(text(v), format!("{v}"));
        }
    }
}
