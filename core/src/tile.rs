//! Lane tiles: one file holding a lane map ready to memory-map, with what it needs to be placed
//! on Earth.
//!
//! Layout (all little-endian):
//!
//! | bytes | field |
//! |---|---|
//! | 0..8 | magic `LANETILE` |
//! | 8..12 | format version (`u32`, [`VERSION`]) |
//! | 12..16 | endianness mark `0x01020304` (`u32`) |
//! | 16..20 | projection (`u32`: 0 tangent, 1 kitti) |
//! | 20..24 | reserved, zero |
//! | 24..40 | origin latitude, longitude (`f64`, degrees, WGS84) |
//! | 40..48 | point spacing the lanes were resampled at (`f64`, metres) |
//! | 48..56, 56..64 | point count, lane count (`u64`) |
//! | 64..72 | KD-tree length in bytes (`u64`) |
//! | 72..104 | bounding box min x, min y, max x, max y (`f64`, metres, map plane) |
//! | 104..112 | payload length in bytes (`u64`) |
//! | 112..120 | XXH3-64 of bytes 0..112 and of the payload |
//! | 120..128 | reserved, zero |
//! | 128.. | payload: the [`LaneMap`] image (arrays at 16-byte-aligned offsets, then the KD-tree) |
//!
//! Loading maps the file read-only, checks the header, the length, the checksum and every array
//! (see [`LaneMap`]), and then uses the mapping in place: no parsing, no copy. A tile must not
//! be modified while mapped: replace it by writing a new file and renaming it over the old one.

use std::path::{Path, PathBuf};

use xxhash_rust::xxh3::Xxh3;

use crate::geo::{MapPlane, Projection};
use crate::lane_map::{LaneMap, LaneMapError, Layout};

/// The tile magic.
pub const MAGIC: [u8; 8] = *b"LANETILE";
/// The format version this build reads and writes.
pub const VERSION: u32 = 1;
const ENDIAN_MARK: u32 = 0x0102_0304;
/// Header length in bytes.
pub const HEADER_LEN: usize = 128;

/// What a tile says about itself.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TileInfo {
    /// The plane the lanes are in.
    pub plane: MapPlane,
    /// The spacing the lanes were resampled at (metres).
    pub spacing_m: f64,
    /// Lane points.
    pub points: u64,
    /// Lanes.
    pub lanes: u64,
    /// Bounding box `[min x, min y, max x, max y]` (metres, map plane).
    pub bounds: [f64; 4],
    /// Payload bytes.
    pub payload_len: u64,
    /// The stored checksum.
    pub checksum: u64,
}

/// A tile that could not be written or loaded.
#[derive(Debug, thiserror::Error)]
pub enum TileError {
    /// The file could not be created, opened, read or mapped.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// Shorter than its header or than the header says.
    #[error("{path}: truncated: {len} bytes, expected {expected}")]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Its length.
        len: u64,
        /// The length the header implies.
        expected: u64,
    },
    /// Not a tile.
    #[error("{path}: not a lane tile (bad magic)")]
    BadMagic {
        /// The file.
        path: PathBuf,
    },
    /// A tile of another format version.
    #[error("{path}: tile format version {found}, this build reads version {VERSION}")]
    BadVersion {
        /// The file.
        path: PathBuf,
        /// The version found.
        found: u32,
    },
    /// Written with another byte order.
    #[error("{path}: the tile is not little-endian")]
    BadEndianness {
        /// The file.
        path: PathBuf,
    },
    /// A header field is out of range.
    #[error("{path}: bad header field {field}: {value}")]
    BadHeader {
        /// The file.
        path: PathBuf,
        /// The field.
        field: &'static str,
        /// Its value.
        value: String,
    },
    /// The checksum does not match: the file was damaged or tampered with.
    #[error("{path}: checksum mismatch (stored {stored:016x}, computed {computed:016x}): the tile is damaged")]
    Checksum {
        /// The file.
        path: PathBuf,
        /// Stored checksum.
        stored: u64,
        /// Computed checksum.
        computed: u64,
    },
    /// The payload does not hold a valid lane map.
    #[error("{path}: {source}")]
    Map {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        source: LaneMapError,
    },
}

fn projection_code(p: Projection) -> u32 {
    match p {
        Projection::Tangent => 0,
        Projection::Kitti => 1,
    }
}

fn bounds(map: &LaneMap) -> [f64; 4] {
    map.points().iter().fold(
        [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ],
        |b, p| {
            [
                b[0].min(p[0]),
                b[1].min(p[1]),
                b[2].max(p[0]),
                b[3].max(p[1]),
            ]
        },
    )
}

fn checksum(header: &[u8], payload: &[u8]) -> u64 {
    let mut h = Xxh3::new();
    h.update(&header[..112]);
    h.update(payload);
    h.digest()
}

/// The header bytes for `map` in `plane`.
fn header(map: &LaneMap, plane: &MapPlane, spacing_m: f64) -> [u8; HEADER_LEN] {
    let mut h = [0u8; HEADER_LEN];
    let layout = map.layout();
    let [min_x, min_y, max_x, max_y] = bounds(map);
    h[0..8].copy_from_slice(&MAGIC);
    h[8..12].copy_from_slice(&VERSION.to_le_bytes());
    h[12..16].copy_from_slice(&ENDIAN_MARK.to_le_bytes());
    h[16..20].copy_from_slice(&projection_code(plane.projection).to_le_bytes());
    for (at, v) in [
        (24, plane.origin_lat),
        (32, plane.origin_lon),
        (40, spacing_m),
        (72, min_x),
        (80, min_y),
        (88, max_x),
        (96, max_y),
    ] {
        h[at..at + 8].copy_from_slice(&v.to_le_bytes());
    }
    for (at, v) in [
        (48, layout.point_count),
        (56, layout.lane_count),
        (64, layout.tree_len()),
        (104, layout.len()),
    ] {
        h[at..at + 8].copy_from_slice(&(v as u64).to_le_bytes());
    }
    let sum = checksum(&h, map.image());
    h[112..120].copy_from_slice(&sum.to_le_bytes());
    h
}

/// Writes `map` (in `plane`, resampled at `spacing_m`) as a tile: to a temporary file beside
/// `path`, then renamed over it, so that a daemon mapping the old tile never sees a half-written
/// one.
pub fn write(
    path: &Path,
    map: &LaneMap,
    plane: &MapPlane,
    spacing_m: f64,
) -> Result<(), TileError> {
    let io = |source| TileError::Io {
        path: path.to_path_buf(),
        source,
    };
    let tmp = path.with_extension("tile.partial");
    let mut bytes = Vec::with_capacity(HEADER_LEN + map.image().len());
    bytes.extend_from_slice(&header(map, plane, spacing_m));
    bytes.extend_from_slice(map.image());
    std::fs::write(&tmp, &bytes).map_err(io)?;
    std::fs::rename(&tmp, path).map_err(io)
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(a)
}

fn f64_at(b: &[u8], at: usize) -> f64 {
    f64::from_bits(u64_at(b, at))
}

/// Checks a tile's header and checksum and returns what it says (the payload itself is checked
/// by [`load`]).
pub fn read_info(path: &Path, bytes: &[u8]) -> Result<TileInfo, TileError> {
    let p = || path.to_path_buf();
    if bytes.len() < HEADER_LEN {
        return Err(TileError::Truncated {
            path: p(),
            len: bytes.len() as u64,
            expected: HEADER_LEN as u64,
        });
    }
    if bytes[0..8] != MAGIC {
        return Err(TileError::BadMagic { path: p() });
    }
    let version = u32_at(bytes, 8);
    if version != VERSION {
        return Err(TileError::BadVersion {
            path: p(),
            found: version,
        });
    }
    if u32_at(bytes, 12) != ENDIAN_MARK {
        return Err(TileError::BadEndianness { path: p() });
    }
    let bad = |field: &'static str, value: String| TileError::BadHeader {
        path: p(),
        field,
        value,
    };
    let projection = match u32_at(bytes, 16) {
        0 => Projection::Tangent,
        1 => Projection::Kitti,
        other => return Err(bad("projection", other.to_string())),
    };
    let payload_len = u64_at(bytes, 104);
    let expected = (HEADER_LEN as u64).saturating_add(payload_len);
    if (bytes.len() as u64) < expected {
        return Err(TileError::Truncated {
            path: p(),
            len: bytes.len() as u64,
            expected,
        });
    }
    if bytes.len() as u64 > expected {
        return Err(bad(
            "payload length",
            format!(
                "{payload_len}, but {} bytes follow the header",
                bytes.len() - HEADER_LEN
            ),
        ));
    }
    let stored = u64_at(bytes, 112);
    let computed = checksum(bytes, &bytes[HEADER_LEN..]);
    if stored != computed {
        return Err(TileError::Checksum {
            path: p(),
            stored,
            computed,
        });
    }
    let (lat, lon, spacing_m) = (f64_at(bytes, 24), f64_at(bytes, 32), f64_at(bytes, 40));
    if !(lat.is_finite() && lat.abs() <= 90.0 && lon.is_finite() && lon.abs() <= 180.0) {
        return Err(bad("origin", format!("({lat}, {lon})")));
    }
    if !(spacing_m.is_finite() && spacing_m >= 0.0) {
        return Err(bad("spacing", spacing_m.to_string()));
    }
    let bounds = [
        f64_at(bytes, 72),
        f64_at(bytes, 80),
        f64_at(bytes, 88),
        f64_at(bytes, 96),
    ];
    Ok(TileInfo {
        plane: MapPlane::new(projection, lat, lon),
        spacing_m,
        points: u64_at(bytes, 48),
        lanes: u64_at(bytes, 56),
        bounds,
        payload_len,
        checksum: stored,
    })
}

/// Memory-maps and validates a tile: header, length, checksum, every array and the KD-tree.
pub fn load(path: &Path) -> Result<(LaneMap, TileInfo), TileError> {
    let io = |source| TileError::Io {
        path: path.to_path_buf(),
        source,
    };
    let file = std::fs::File::open(path).map_err(io)?;
    // SAFETY: the mapping is read-only and tiles are replaced by rename, never modified in place
    // (see the module docs); every byte is validated before use.
    let mapping = unsafe { memmap2::Mmap::map(&file) }.map_err(io)?;
    let info = read_info(path, &mapping)?;
    let to_usize = |v: u64, field: &'static str| {
        usize::try_from(v).map_err(|_| TileError::BadHeader {
            path: path.to_path_buf(),
            field,
            value: v.to_string(),
        })
    };
    let layout = Layout::new(
        to_usize(info.points, "point count")?,
        to_usize(info.lanes, "lane count")?,
        to_usize(u64_at(&mapping, 64), "tree length")?,
    );
    if layout.len() as u64 != info.payload_len {
        return Err(TileError::BadHeader {
            path: path.to_path_buf(),
            field: "payload length",
            value: format!("{}, the counts need {}", info.payload_len, layout.len()),
        });
    }
    let map =
        LaneMap::from_mapping(mapping, HEADER_LEN, layout).map_err(|source| TileError::Map {
            path: path.to_path_buf(),
            source,
        })?;
    Ok((map, info))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lane_map::Lane;
    use proptest::prelude::*;

    fn sample_map() -> LaneMap {
        let lanes: Vec<Lane> = (0..20)
            .map(|k| Lane {
                id: k,
                points: (0..30).map(|i| [i as f64 * 3.0, k as f64 * 3.5]).collect(),
            })
            .collect();
        LaneMap::new(&lanes).unwrap()
    }

    fn written(dir: &Path) -> (PathBuf, Vec<u8>) {
        let path = dir.join("t.tile");
        let plane = MapPlane::new(Projection::Kitti, 48.98, 8.39);
        write(&path, &sample_map(), &plane, 3.0).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        (path, bytes)
    }

    #[test]
    fn round_trip_keeps_everything() {
        let dir = tempfile::tempdir().unwrap();
        let (path, _) = written(dir.path());
        let (map, info) = load(&path).unwrap();
        let original = sample_map();
        assert_eq!(map.image(), original.image());
        assert_eq!(info.plane, MapPlane::new(Projection::Kitti, 48.98, 8.39));
        assert_eq!((info.points, info.lanes), (600, 20));
        assert_eq!(info.bounds, [0.0, 0.0, 87.0, 66.5]);
        let mut a = Vec::new();
        let mut b = Vec::new();
        map.nearest([10.0, 10.0], 7, &mut a);
        original.nearest([10.0, 10.0], 7, &mut b);
        assert_eq!(a, b);
    }

    #[test]
    fn damage_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let (path, bytes) = written(dir.path());
        let check = |b: &[u8], what: &str| {
            std::fs::write(&path, b).unwrap();
            let e = load(&path).unwrap_err().to_string();
            assert!(e.contains(what), "{e}");
        };
        check(&bytes[..bytes.len() - 10], "truncated");
        check(&bytes[..50], "truncated");
        let mut b = bytes.clone();
        b[0] = b'X';
        check(&b, "bad magic");
        let mut b = bytes.clone();
        b[8] = 9;
        check(&b, "version 9");
        let mut b = bytes.clone();
        b[12..16].copy_from_slice(&0x0403_0201u32.to_le_bytes());
        check(&b, "little-endian");
        let mut b = bytes.clone();
        b[HEADER_LEN + 5] ^= 1;
        check(&b, "checksum mismatch");
    }

    #[test]
    fn inconsistent_content_with_a_valid_checksum_is_refused() {
        // Tampering that recomputes the checksum is caught by the content checks.
        let dir = tempfile::tempdir().unwrap();
        let (path, mut bytes) = written(dir.path());
        let at = HEADER_LEN + 600 * 16; // the first segment start
        bytes[at..at + 4].copy_from_slice(&7u32.to_le_bytes());
        let sum = checksum(&bytes, &bytes[HEADER_LEN..]);
        bytes[112..120].copy_from_slice(&sum.to_le_bytes());
        std::fs::write(&path, &bytes).unwrap();
        let e = load(&path).unwrap_err().to_string();
        assert!(e.contains("segment of point 0"), "{e}");
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 2000, rng_seed: proptest::test_runner::RngSeed::Fixed(3), ..ProptestConfig::default() })]
        /// Any flipped byte anywhere: the load is an error, never a panic or a map that did
        /// not pass validation.
        #[test]
        fn flipped_bytes_are_always_caught(position in 0usize..100_000, bit in 0u8..8) {
            let dir = tempfile::tempdir().unwrap();
            let (path, mut bytes) = written(dir.path());
            let at = position % bytes.len();
            bytes[at] ^= 1 << bit;
            std::fs::write(&path, &bytes).unwrap();
            prop_assert!(load(&path).is_err(), "flip at byte {} went unnoticed", at);
        }
    }
}
