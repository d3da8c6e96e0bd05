//! Lane tiles: one file holding a lane map, the plane it lives in and how its lanes were derived.
//!
//! A tile is untrusted input. Loading reads it into memory the loader owns (bounded by the
//! file's size, regular files only), checks every header field, the checksum and every array
//! with checked arithmetic, and builds the KD-tree itself from the validated points: no byte
//! sequence can make it read out of bounds, and a file changed after loading changes nothing.
//!
//! Layout (all little-endian, format version 3):
//!
//! | bytes | field |
//! |---|---|
//! | 0..8 | magic `LANETILE` |
//! | 8..12 | format version (`u32`, [`VERSION`]) |
//! | 12..16 | endianness mark `0x01020304` (`u32`) |
//! | 16..20 | projection (`u32`: 0 tangent, 1 kitti) |
//! | 20..24 | traffic side (`u32`: 0 right, 1 left) |
//! | 24..40 | origin latitude, longitude (`f64`, degrees, WGS84) |
//! | 40..48 | point spacing the lanes were resampled at (`f64`, metres) |
//! | 48..56, 56..64 | point count, lane count (`u64`) |
//! | 64..72 | unmarked-street offset scale (`f64`; 0 unless flag bit 0) |
//! | 72..104 | bounding box min x, min y, max x, max y (`f64`, metres, map plane) |
//! | 104..112 | payload length in bytes (`u64`) |
//! | 112..116 | road classes lanes were derived from (`u32`, bit per [`RoadClass`] code) |
//! | 116..120 | flags (`u32`): bit 0 lanes from raw OSM ways (the offset scale applies), bit 1 signed, bit 2 grid cell |
//! | 120..152 | signer's ed25519 public key (zero unless signed) |
//! | 152..216 | ed25519 signature (zero unless signed) |
//! | 216..248 | a grid cell's own square: min x, min y, max x, max y (`f64`, metres); zero unless a cell |
//! | 248..256 | map version (`u64`, at most [`MAX_MAP_VERSION`]; 0 unless the builder gave one) |
//! | 256..264 | XXH3-64 of bytes 0..256 and of the payload |
//! | 264.. | payload |
//!
//! A signed tile (flag bit 1, [`sign`]) carries the signer's public key and an ed25519 signature
//! of every byte but the signature itself and the checksum; loading verifies it. The map version
//! is the builder's number for the build ([`set_map_version`]): a daemon can refuse a map older
//! than it should serve (a signature names who built a map, the version which build it is).
//!
//! Payload: lane offsets (`u32` x lanes + 1), lane ids (`u64` x lanes), lane info (class `u8`,
//! flags `u8`, per lane), points (`f64` x, y per point), and in a grid cell the pieces (per lane:
//! `u32` index of the whole lane in the grid's map, `u32` index of the piece's first point in
//! that lane; see [`crate::grid`]); each array starts at a multiple of 8. Segment directions and
//! the KD-tree are derived from the points at load.

use std::path::{Path, PathBuf};

use ed25519_dalek::{Signature, Signer, VerifyingKey};
use xxhash_rust::xxh3::Xxh3;

pub use ed25519_dalek::SigningKey;

use crate::geo::{check_lat_lon, MapPlane, Projection};
use crate::input::InputError;
use crate::lane_geometry::{LaneGeometry, LaneInfo, RoadClass, RoadClasses, Traffic};
use crate::lane_map::{LaneMap, LaneMapError, MAX_POINTS};

/// The tile magic.
pub const MAGIC: [u8; 8] = *b"LANETILE";
/// The format version this build reads and writes.
pub const VERSION: u32 = 3;
const ENDIAN_MARK: u32 = 0x0102_0304;
/// Header length in bytes.
pub const HEADER_LEN: usize = 264;
/// Largest tile this build loads (bytes): far above any real map (a 1 M point tile is 17 MB),
/// small enough that a bogus size is refused before anything is allocated.
pub const MAX_TILE_BYTES: u64 = 1 << 32;

const FLAG_OSM_LANES: u32 = 1;
const FLAG_SIGNED: u32 = 1 << 1;
const FLAG_GRID_CELL: u32 = 1 << 2;
const KNOWN_FLAGS: u32 = FLAG_OSM_LANES | FLAG_SIGNED | FLAG_GRID_CELL;
const SIGNER_AT: usize = 120;
const SIGNATURE_AT: usize = 152;
const SIGNATURE_END: usize = 216;
const CELL_SQUARE_AT: usize = 216;
const MAP_VERSION_AT: usize = 248;
const CHECKSUM_AT: usize = 256;
/// The largest map version a tile or grid may carry: the largest integer a TOML file (a grid's
/// manifest, the daemon's configuration) holds.
pub const MAX_MAP_VERSION: u64 = i64::MAX as u64;

/// What a tile says about itself.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TileInfo {
    /// The plane the lanes are in.
    pub plane: MapPlane,
    /// The spacing the lanes were resampled at (metres).
    pub spacing_m: f64,
    /// How the lanes were derived.
    pub geometry: LaneGeometry,
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
    /// The ed25519 public key whose signature the tile carries, verified (`None`: unsigned).
    pub signer: Option<[u8; 32]>,
    /// The builder's number for this build of the map ([`set_map_version`]; 0: none given).
    pub map_version: u64,
    /// For one cell of a tile grid, the cell's own square `[min x, min y, max x, max y]`
    /// (metres, map plane); its lanes reach beyond it by the grid's margin. `None`: a whole map.
    pub cell: Option<[f64; 4]>,
}

/// Where a piece of a grid cell comes from: the index of its whole lane in the grid's map, and
/// the index of the piece's first point in that lane.
pub type PieceOrigin = [u32; 2];

/// A tile that could not be written or loaded.
#[derive(Debug, thiserror::Error)]
pub enum TileError {
    /// The file could not be written, opened or read, is not a regular file (a FIFO, a device,
    /// a directory) or is larger than [`MAX_TILE_BYTES`].
    #[error(transparent)]
    Input(#[from] InputError),
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
    /// OSM road data (XML or PBF, raw OSM or Lanelet2) where a tile was expected.
    #[error(
        "{path}: OSM road data, not a lane tile: compile it into one with `lanealign-map compile` \
         (`lanealign correct` also takes it as --osm)"
    )]
    RoadData {
        /// The file.
        path: PathBuf,
    },
    /// A map version no tile or grid may carry.
    #[error(
        "map version {map_version}: at most {MAX_MAP_VERSION} (the largest integer TOML holds)"
    )]
    MapVersion {
        /// The version asked for (wider than a version may be, so that an interface taking
        /// larger integers, Python's, names the one it was given).
        map_version: u128,
    },
    /// A tile of another format version.
    #[error("{path}: tile format version {found}, this build reads version {VERSION}; compile it again with this build's lanealign-map")]
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
    /// The tile is signed, but the signature does not match its bytes.
    #[error("{path}: the signature does not match the tile: it was changed after signing")]
    BadSignature {
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
    /// A cell of a tile grid where a whole map was expected, or the other way round.
    #[error("{path}: {what}")]
    GridCell {
        /// The file.
        path: PathBuf,
        /// What was expected instead.
        what: &'static str,
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

/// Where each payload array lies (byte ranges), from the counts, with checked arithmetic.
struct PayloadLayout {
    offsets: std::ops::Range<usize>,
    ids: std::ops::Range<usize>,
    info: std::ops::Range<usize>,
    points: std::ops::Range<usize>,
    pieces: Option<std::ops::Range<usize>>,
}

impl PayloadLayout {
    fn new(points: usize, lanes: usize, cell: bool) -> Option<PayloadLayout> {
        let mut at = 0usize;
        let mut section = |len: usize| -> Option<std::ops::Range<usize>> {
            let range = at..at.checked_add(len)?;
            at = range.end.checked_next_multiple_of(8)?;
            Some(range)
        };
        Some(PayloadLayout {
            offsets: section(lanes.checked_add(1)?.checked_mul(4)?)?,
            ids: section(lanes.checked_mul(8)?)?,
            info: section(lanes.checked_mul(2)?)?,
            points: section(points.checked_mul(16)?)?,
            pieces: if cell {
                Some(section(lanes.checked_mul(8)?)?)
            } else {
                None
            },
        })
    }

    fn len(&self) -> usize {
        self.pieces.as_ref().unwrap_or(&self.points).end
    }
}

fn projection_code(p: Projection) -> u32 {
    match p {
        Projection::Tangent => 0,
        Projection::Kitti => 1,
    }
}

fn traffic_code(t: Traffic) -> u32 {
    match t {
        Traffic::Right => 0,
        Traffic::Left => 1,
    }
}

/// The bounding box `[min x, min y, max x, max y]` of `points` (metres; infinities when empty).
pub fn bounds(points: &[[f64; 2]]) -> [f64; 4] {
    points.iter().fold(
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

/// What a tile's signature covers: every byte but the signature and the checksum (the signature
/// field counts as zero).
fn signed_message(bytes: &[u8]) -> Vec<u8> {
    let mut message = Vec::with_capacity(bytes.len());
    message.extend_from_slice(&bytes[..SIGNATURE_AT]);
    message.extend_from_slice(&[0; SIGNATURE_END - SIGNATURE_AT]);
    message.extend_from_slice(&bytes[SIGNATURE_END..CHECKSUM_AT]);
    message.extend_from_slice(&bytes[HEADER_LEN..]);
    message
}

/// Signs encoded tile bytes (from [`encode`]) with `key`: sets the signed flag, records the
/// public key and the ed25519 signature, and updates the checksum.
pub fn sign(bytes: &mut [u8], key: &SigningKey) {
    if bytes.len() < HEADER_LEN {
        return;
    }
    let flags = u32_at(bytes, 116) | FLAG_SIGNED;
    put(bytes, 116, &flags.to_le_bytes());
    put(bytes, SIGNER_AT, &key.verifying_key().to_bytes());
    let signature = key.sign(&signed_message(bytes));
    put(bytes, SIGNATURE_AT, &signature.to_bytes());
    seal(bytes);
}

/// Records the builder's number for this build of the map in encoded tile bytes (from
/// [`encode`]) and updates the checksum. Before [`sign`]: the signature covers it. Versions above
/// [`MAX_MAP_VERSION`] are refused.
pub fn set_map_version(bytes: &mut [u8], map_version: u64) -> Result<(), TileError> {
    check_map_version(map_version)?;
    if bytes.len() >= HEADER_LEN {
        put(bytes, MAP_VERSION_AT, &map_version.to_le_bytes());
        seal(bytes);
    }
    Ok(())
}

/// Refuses a map version above [`MAX_MAP_VERSION`].
pub fn check_map_version(map_version: u64) -> Result<(), TileError> {
    if map_version > MAX_MAP_VERSION {
        return Err(TileError::MapVersion {
            map_version: map_version.into(),
        });
    }
    Ok(())
}

/// Verifies a signed tile's signature; the signer's public key when it holds.
fn verify_signature(path: &Path, bytes: &[u8]) -> Result<[u8; 32], TileError> {
    let mut key = [0; 32];
    key.copy_from_slice(&bytes[SIGNER_AT..SIGNATURE_AT]);
    let mut signature = [0; 64];
    signature.copy_from_slice(&bytes[SIGNATURE_AT..SIGNATURE_END]);
    let verifying = VerifyingKey::from_bytes(&key).map_err(|_| TileError::BadHeader {
        path: path.to_path_buf(),
        field: "signer",
        value: "not an ed25519 public key".into(),
    })?;
    verifying
        .verify_strict(&signed_message(bytes), &Signature::from_bytes(&signature))
        .map_err(|_| TileError::BadSignature {
            path: path.to_path_buf(),
        })?;
    Ok(key)
}

/// A 32-byte key as 64 lowercase hex digits.
pub fn key_hex(key: &[u8; 32]) -> String {
    hex(key)
}

/// A 32-byte key from 64 hex digits (surrounding whitespace ignored); `None` if it is not one.
pub fn parse_key_hex(text: &str) -> Option<[u8; 32]> {
    bytes_of_hex(text.trim())
}

/// Bytes as lowercase hex digits, two per byte.
pub(crate) fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// `N` bytes from exactly `2 N` hex digits (no sign, no space); `None` if `text` is not that.
pub(crate) fn bytes_of_hex<const N: usize>(text: &str) -> Option<[u8; N]> {
    let digits = text.as_bytes();
    if digits.len() != 2 * N {
        return None;
    }
    let nibble = |d: u8| char::from(d).to_digit(16);
    let mut bytes = [0; N];
    for (byte, pair) in bytes.iter_mut().zip(digits.chunks_exact(2)) {
        *byte = u8::try_from(nibble(pair[0])? << 4 | nibble(pair[1])?).ok()?;
    }
    Some(bytes)
}

/// Writes the checksum of whole tile bytes into their header: for tools that edit a tile's
/// bytes on purpose (tests, fuzzing). Does nothing to bytes shorter than a header.
pub fn seal(bytes: &mut [u8]) {
    if bytes.len() >= HEADER_LEN {
        let sum = checksum(bytes, &bytes[HEADER_LEN..]);
        bytes[CHECKSUM_AT..HEADER_LEN].copy_from_slice(&sum.to_le_bytes());
    }
}

fn checksum(header: &[u8], payload: &[u8]) -> u64 {
    let mut h = Xxh3::new();
    h.update(&header[..CHECKSUM_AT]);
    h.update(payload);
    h.digest()
}

fn put(bytes: &mut [u8], at: usize, v: &[u8]) {
    bytes[at..at + v.len()].copy_from_slice(v);
}

/// The payload bytes of `map` (and of its pieces' origins, for a grid cell).
fn payload(map: &LaneMap, pieces: Option<&[PieceOrigin]>) -> Vec<u8> {
    let layout = PayloadLayout::new(map.len(), map.lane_count(), pieces.is_some())
        .expect("a built map's counts fit in memory");
    let mut out = vec![0u8; layout.len()];
    for (k, o) in map.lane_offsets().iter().enumerate() {
        put(&mut out, layout.offsets.start + 4 * k, &o.to_le_bytes());
    }
    for (k, id) in map.lane_ids().iter().enumerate() {
        put(&mut out, layout.ids.start + 8 * k, &id.to_le_bytes());
    }
    for (k, info) in map.lane_info().iter().enumerate() {
        put(
            &mut out,
            layout.info.start + 2 * k,
            &[info.class as u8, info.flags],
        );
    }
    for (j, p) in map.points().iter().enumerate() {
        put(&mut out, layout.points.start + 16 * j, &p[0].to_le_bytes());
        put(
            &mut out,
            layout.points.start + 16 * j + 8,
            &p[1].to_le_bytes(),
        );
    }
    if let (Some(range), Some(pieces)) = (&layout.pieces, pieces) {
        for (k, [lane, first]) in pieces.iter().enumerate() {
            put(&mut out, range.start + 8 * k, &lane.to_le_bytes());
            put(&mut out, range.start + 8 * k + 4, &first.to_le_bytes());
        }
    }
    out
}

/// True for a lane point spacing (metres) a tile header or a grid manifest may record: finite and
/// 0 or more.
pub fn is_recorded_spacing(spacing_m: f64) -> bool {
    spacing_m.is_finite() && spacing_m >= 0.0
}

/// The bytes of a tile of `map` in `plane`, resampled at `spacing_m`, derived as `geometry`.
pub fn encode(map: &LaneMap, plane: &MapPlane, spacing_m: f64, geometry: &LaneGeometry) -> Vec<u8> {
    encode_parts(map, plane, spacing_m, geometry, None)
}

/// The bytes of one cell of a tile grid: `map`'s lanes are pieces of the grid's lanes, lane `k`
/// coming from `pieces[k]`; `square` is the cell's own square (metres, map plane).
pub fn encode_cell(
    map: &LaneMap,
    pieces: &[PieceOrigin],
    square: [f64; 4],
    plane: &MapPlane,
    spacing_m: f64,
    geometry: &LaneGeometry,
) -> Vec<u8> {
    encode_parts(map, plane, spacing_m, geometry, Some((pieces, square)))
}

fn encode_parts(
    map: &LaneMap,
    plane: &MapPlane,
    spacing_m: f64,
    geometry: &LaneGeometry,
    cell: Option<(&[PieceOrigin], [f64; 4])>,
) -> Vec<u8> {
    let payload = payload(map, cell.map(|c| c.0));
    let mut h = [0u8; HEADER_LEN];
    put(&mut h, 0, &MAGIC);
    put(&mut h, 8, &VERSION.to_le_bytes());
    put(&mut h, 12, &ENDIAN_MARK.to_le_bytes());
    put(&mut h, 16, &projection_code(plane.projection).to_le_bytes());
    put(&mut h, 20, &traffic_code(geometry.traffic).to_le_bytes());
    let [min_x, min_y, max_x, max_y] = bounds(map.points());
    for (at, v) in [
        (24, plane.origin_lat),
        (32, plane.origin_lon),
        (40, spacing_m),
        (64, geometry.unmarked_offset_scale.unwrap_or(0.0)),
        (72, min_x),
        (80, min_y),
        (88, max_x),
        (96, max_y),
    ] {
        put(&mut h, at, &v.to_le_bytes());
    }
    for (at, v) in [
        (48, map.len()),
        (56, map.lane_count()),
        (104, payload.len()),
    ] {
        put(&mut h, at, &(v as u64).to_le_bytes());
    }
    put(&mut h, 112, &geometry.classes.bits().to_le_bytes());
    let mut flags = if geometry.unmarked_offset_scale.is_some() {
        FLAG_OSM_LANES
    } else {
        0
    };
    if let Some((_, square)) = cell {
        flags |= FLAG_GRID_CELL;
        for (k, v) in square.iter().enumerate() {
            put(&mut h, CELL_SQUARE_AT + 8 * k, &v.to_le_bytes());
        }
    }
    put(&mut h, 116, &flags.to_le_bytes());
    let mut bytes = Vec::with_capacity(HEADER_LEN + payload.len());
    bytes.extend_from_slice(&h);
    bytes.extend_from_slice(&payload);
    seal(&mut bytes);
    bytes
}

/// Writes a tile: to a temporary file beside `path`, then renamed over it, so that a reader
/// never sees a half-written tile.
pub fn write(
    path: &Path,
    map: &LaneMap,
    plane: &MapPlane,
    spacing_m: f64,
    geometry: &LaneGeometry,
) -> Result<(), TileError> {
    write_bytes(path, &encode(map, plane, spacing_m, geometry))
}

/// Writes tile bytes atomically (temporary file beside `path`, then rename).
pub fn write_bytes(path: &Path, bytes: &[u8]) -> Result<(), TileError> {
    Ok(crate::input::write_atomic(path, bytes)?)
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    let mut a = [0u8; 4];
    a.copy_from_slice(&b[at..at + 4]);
    u32::from_le_bytes(a)
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(a)
}

fn f64_at(b: &[u8], at: usize) -> f64 {
    f64::from_bits(u64_at(b, at))
}

/// Whether `bytes` begin as OSM road data does: XML whose first kilobyte opens an `<osm>`
/// element (after an optional byte-order mark), or PBF, whose first block header names its type
/// `OSMHeader`.
fn is_road_data(bytes: &[u8]) -> bool {
    let start = &bytes[..bytes.len().min(1024)];
    let xml = start
        .strip_prefix(b"\xef\xbb\xbf")
        .unwrap_or(start)
        .trim_ascii_start()
        .starts_with(b"<")
        && start.windows(4).any(|w| w == b"<osm");
    let pbf = start.len() > 4
        && start[4..start.len().min(32)]
            .windows(9)
            .any(|w| w == b"OSMHeader");
    xml || pbf
}

/// Checks a tile's header and checksum and returns what it says (the payload's content is
/// checked by [`decode`]).
pub fn read_info(path: &Path, bytes: &[u8]) -> Result<TileInfo, TileError> {
    let p = || path.to_path_buf();
    let bad = |field: &'static str, value: String| TileError::BadHeader {
        path: p(),
        field,
        value,
    };
    if bytes.get(0..8) != Some(&MAGIC[..]) && is_road_data(bytes) {
        return Err(TileError::RoadData { path: p() });
    }
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
    let stored = u64_at(bytes, CHECKSUM_AT);
    let computed = checksum(bytes, &bytes[HEADER_LEN..]);
    if stored != computed {
        return Err(TileError::Checksum {
            path: p(),
            stored,
            computed,
        });
    }
    let projection = match u32_at(bytes, 16) {
        0 => Projection::Tangent,
        1 => Projection::Kitti,
        other => return Err(bad("projection", other.to_string())),
    };
    let traffic = match u32_at(bytes, 20) {
        0 => Traffic::Right,
        1 => Traffic::Left,
        other => return Err(bad("traffic", other.to_string())),
    };
    let (lat, lon, spacing_m) = (f64_at(bytes, 24), f64_at(bytes, 32), f64_at(bytes, 40));
    check_lat_lon(lat, lon).map_err(|e| bad("origin", e.to_string()))?;
    if !is_recorded_spacing(spacing_m) {
        return Err(bad("spacing", spacing_m.to_string()));
    }
    let flags = u32_at(bytes, 116);
    if flags & !KNOWN_FLAGS != 0 {
        return Err(bad("flags", format!("{flags:#x}")));
    }
    let signer = if flags & FLAG_SIGNED != 0 {
        Some(verify_signature(path, bytes)?)
    } else if bytes[SIGNER_AT..SIGNATURE_END].iter().any(|&b| b != 0) {
        return Err(bad("signature", "present in an unsigned tile".into()));
    } else {
        None
    };
    let cell = if flags & FLAG_GRID_CELL != 0 {
        let square: [f64; 4] = std::array::from_fn(|k| f64_at(bytes, CELL_SQUARE_AT + 8 * k));
        let valid =
            square.iter().all(|v| v.is_finite()) && square[0] < square[2] && square[1] < square[3];
        if !valid {
            return Err(bad("cell square", format!("{square:?}")));
        }
        Some(square)
    } else if bytes[CELL_SQUARE_AT..MAP_VERSION_AT]
        .iter()
        .any(|&b| b != 0)
    {
        return Err(bad("reserved bytes 216..248", "not zero".into()));
    } else {
        None
    };
    let map_version = u64_at(bytes, MAP_VERSION_AT);
    if map_version > MAX_MAP_VERSION {
        return Err(bad(
            "map version",
            format!("{map_version}, above {MAX_MAP_VERSION}"),
        ));
    }
    let scale = f64_at(bytes, 64);
    let unmarked_offset_scale = if flags & FLAG_OSM_LANES != 0 {
        if crate::lane_geometry::check_unmarked_offset_scale(scale).is_err() {
            return Err(bad("unmarked offset scale", scale.to_string()));
        }
        Some(scale)
    } else {
        if scale.to_bits() != 0 {
            return Err(bad(
                "unmarked offset scale",
                format!("{scale} without OSM lanes"),
            ));
        }
        None
    };
    let classes = RoadClasses::from_bits(u32_at(bytes, 112))
        .ok_or_else(|| bad("road classes", format!("{:#x}", u32_at(bytes, 112))))?;
    let bounds = [
        f64_at(bytes, 72),
        f64_at(bytes, 80),
        f64_at(bytes, 88),
        f64_at(bytes, 96),
    ];
    Ok(TileInfo {
        plane: MapPlane::new(projection, lat, lon),
        spacing_m,
        geometry: LaneGeometry {
            traffic,
            classes,
            unmarked_offset_scale,
        },
        points: u64_at(bytes, 48),
        lanes: u64_at(bytes, 56),
        bounds,
        payload_len,
        checksum: stored,
        signer,
        map_version,
        cell,
    })
}

/// Decodes and validates the bytes of a whole-map tile; `path` names the source in errors.
pub fn decode(path: &Path, bytes: &[u8]) -> Result<(LaneMap, TileInfo), TileError> {
    match decode_parts(path, bytes)? {
        (map, info, None) => Ok((map, info)),
        (_, _, Some(_)) => Err(TileError::GridCell {
            path: path.to_path_buf(),
            what: "one cell of a tile grid, not a whole map: give the grid's folder (with manifest.toml)",
        }),
    }
}

/// Decodes and validates the bytes of one cell of a tile grid: its pieces as a map, what the
/// tile says about itself, and where each piece comes from (one per lane, in map order).
pub fn decode_cell(
    path: &Path,
    bytes: &[u8],
) -> Result<(LaneMap, TileInfo, Vec<PieceOrigin>), TileError> {
    match decode_parts(path, bytes)? {
        (map, info, Some(pieces)) => Ok((map, info, pieces)),
        (_, _, None) => Err(TileError::GridCell {
            path: path.to_path_buf(),
            what: "a whole-map tile where a grid cell was expected",
        }),
    }
}

fn decode_parts(
    path: &Path,
    bytes: &[u8],
) -> Result<(LaneMap, TileInfo, Option<Vec<PieceOrigin>>), TileError> {
    let info = read_info(path, bytes)?;
    let bad = |field: &'static str, value: String| TileError::BadHeader {
        path: path.to_path_buf(),
        field,
        value,
    };
    let points = usize::try_from(info.points)
        .ok()
        .filter(|&n| n <= MAX_POINTS)
        .ok_or_else(|| bad("point count", info.points.to_string()))?;
    let lanes = usize::try_from(info.lanes)
        .ok()
        .filter(|&l| l <= points)
        .ok_or_else(|| bad("lane count", format!("{} for {points} points", info.lanes)))?;
    let layout = PayloadLayout::new(points, lanes, info.cell.is_some())
        .filter(|l| l.len() as u64 == info.payload_len)
        .ok_or_else(|| {
            bad(
                "payload length",
                format!(
                    "{} does not fit {points} points in {lanes} lanes",
                    info.payload_len
                ),
            )
        })?;
    let payload = &bytes[HEADER_LEN..];
    // The padding between arrays is covered by the checksum and must be zero too.
    let mut covered = vec![false; payload.len()];
    for r in [&layout.offsets, &layout.ids, &layout.info, &layout.points]
        .into_iter()
        .chain(&layout.pieces)
    {
        covered[r.clone()].iter_mut().for_each(|c| *c = true);
    }
    if payload.iter().zip(&covered).any(|(&b, &c)| !c && b != 0) {
        return Err(bad("payload padding", "not zero".into()));
    }
    let offsets = (0..=lanes)
        .map(|k| u32_at(payload, layout.offsets.start + 4 * k))
        .collect();
    let ids = (0..lanes)
        .map(|k| u64_at(payload, layout.ids.start + 8 * k))
        .collect();
    let info_bytes = &payload[layout.info.clone()];
    let lane_info = info_bytes
        .chunks_exact(2)
        .map(|c| {
            RoadClass::from_code(c[0])
                .map(|class| LaneInfo::new(class, c[1]))
                .ok_or_else(|| bad("lane road class", c[0].to_string()))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let pts = (0..points)
        .map(|j| {
            let at = layout.points.start + 16 * j;
            [f64_at(payload, at), f64_at(payload, at + 8)]
        })
        .collect();
    let map =
        LaneMap::from_arrays(offsets, ids, lane_info, pts).map_err(|source| TileError::Map {
            path: path.to_path_buf(),
            source,
        })?;
    if bounds(map.points()) != info.bounds {
        return Err(bad(
            "bounds",
            format!("{:?} do not match the points", info.bounds),
        ));
    }
    let pieces = layout.pieces.map(|range| {
        (0..lanes)
            .map(|k| {
                let at = range.start + 8 * k;
                [u32_at(payload, at), u32_at(payload, at + 4)]
            })
            .collect::<Vec<_>>()
    });
    if let Some(pieces) = &pieces {
        check_pieces(pieces, map.lane_offsets()).map_err(|value| bad("pieces", value))?;
    }
    Ok((map, info, pieces))
}

/// A cell's pieces come in (lane, first point) order, one run each, and fit in a `u32` index.
fn check_pieces(pieces: &[PieceOrigin], lane_offsets: &[u32]) -> Result<(), String> {
    for (k, w) in lane_offsets.windows(2).enumerate() {
        let [lane, first] = pieces[k];
        if first.checked_add(w[1] - w[0]).is_none() {
            return Err(format!(
                "piece {k} of lane {lane} runs past the largest point index"
            ));
        }
    }
    match pieces.windows(2).position(|w| w[0] >= w[1]) {
        Some(k) => Err(format!("pieces {k} and {} are out of order", k + 1)),
        None => Ok(()),
    }
}

/// Loads a tile: reads it into memory (bounded), validates everything and builds the map. The
/// map owns its data: the file can change or vanish afterwards without effect.
pub fn load(path: &Path) -> Result<(LaneMap, TileInfo), TileError> {
    let bytes = crate::input::read_regular_file(path, MAX_TILE_BYTES)?;
    decode(path, &bytes)
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
                info: LaneInfo::new(RoadClass::Residential, LaneInfo::UNMARKED),
                points: (0..30).map(|i| [i as f64 * 3.0, k as f64 * 3.5]).collect(),
            })
            .collect();
        LaneMap::new(&lanes).unwrap()
    }

    fn plane() -> MapPlane {
        MapPlane::new(Projection::Kitti, 48.98, 8.39)
    }

    fn sample_bytes() -> Vec<u8> {
        encode(&sample_map(), &plane(), 3.0, &LaneGeometry::default())
    }

    fn resealed(mut bytes: Vec<u8>) -> Vec<u8> {
        seal(&mut bytes);
        bytes
    }

    #[test]
    fn signed_tiles_verify_and_any_change_is_refused() {
        let key = SigningKey::from_bytes(&[7; 32]);
        let mut bytes = sample_bytes();
        let p = Path::new("s.tile");
        assert_eq!(decode(p, &bytes).unwrap().1.signer, None);
        sign(&mut bytes, &key);
        let (_, info) = decode(p, &bytes).unwrap();
        assert_eq!(info.signer, Some(key.verifying_key().to_bytes()));
        assert_eq!(parse_key_hex(&key_hex(&info.signer.unwrap())), info.signer);
        // Only hex digits: `u8::from_str_radix` took "+f" as 15, so a key with signs was read.
        for text in [
            "+f".repeat(32),
            "0".repeat(63),
            "g".repeat(64),
            " 0".repeat(32),
        ] {
            assert_eq!(parse_key_hex(&text), None, "{text}");
        }
        // A changed point, resealed so that only the signature can tell.
        let mut changed = bytes.clone();
        let last = changed.len() - 3;
        changed[last] ^= 1;
        seal(&mut changed);
        let e = decode(p, &changed).unwrap_err().to_string();
        assert!(e.contains("signature does not match"), "{e}");
        // Another key put in place of the signer's.
        let mut swapped = bytes.clone();
        put(
            &mut swapped,
            SIGNER_AT,
            &SigningKey::from_bytes(&[8; 32]).verifying_key().to_bytes(),
        );
        seal(&mut swapped);
        assert!(matches!(
            decode(p, &swapped),
            Err(TileError::BadSignature { .. })
        ));
    }

    #[test]
    fn the_map_version_is_carried_signed_and_bounded() {
        let p = Path::new("v.tile");
        let mut bytes = sample_bytes();
        assert_eq!(decode(p, &bytes).unwrap().1.map_version, 0);
        set_map_version(&mut bytes, 20_261_207).unwrap();
        assert_eq!(decode(p, &bytes).unwrap().1.map_version, 20_261_207);
        set_map_version(&mut bytes, MAX_MAP_VERSION).unwrap();
        assert_eq!(decode(p, &bytes).unwrap().1.map_version, MAX_MAP_VERSION);
        let e = set_map_version(&mut bytes, MAX_MAP_VERSION + 1).unwrap_err();
        assert!(e.to_string().contains("at most 9223372036854775807"), "{e}");
        // A version no builder could have written, resealed: refused by the reader too.
        let mut beyond = bytes.clone();
        put(&mut beyond, MAP_VERSION_AT, &u64::MAX.to_le_bytes());
        seal(&mut beyond);
        let e = decode(p, &beyond).unwrap_err().to_string();
        assert!(e.contains("map version"), "{e}");
        // The signature covers the version: an older number put in a signed tile is refused.
        set_map_version(&mut bytes, 7).unwrap();
        sign(&mut bytes, &SigningKey::from_bytes(&[7; 32]));
        assert_eq!(decode(p, &bytes).unwrap().1.map_version, 7);
        let mut rolled_back = bytes.clone();
        put(&mut rolled_back, MAP_VERSION_AT, &6u64.to_le_bytes());
        seal(&mut rolled_back);
        assert!(matches!(
            decode(p, &rolled_back),
            Err(TileError::BadSignature { .. })
        ));
    }

    #[test]
    fn round_trip_keeps_everything() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.tile");
        let original = sample_map();
        write(&path, &original, &plane(), 3.0, &LaneGeometry::default()).unwrap();
        let (map, info) = load(&path).unwrap();
        assert_eq!(map.points(), original.points());
        assert_eq!(map.lane_ids(), original.lane_ids());
        assert_eq!(map.lane_info(), original.lane_info());
        assert_eq!(info.plane, plane());
        assert_eq!(info.geometry, LaneGeometry::default());
        assert_eq!((info.points, info.lanes), (600, 20));
        assert_eq!(info.bounds, [0.0, 0.0, 87.0, 66.5]);
        let (mut a, mut b) = (Vec::new(), Vec::new());
        map.nearest([10.0, 10.0], 7, &mut a);
        original.nearest([10.0, 10.0], 7, &mut b);
        assert_eq!(a, b);
        // The file is not needed after loading.
        std::fs::remove_file(&path).unwrap();
        assert_eq!(map.len(), 600);
    }

    #[test]
    fn damage_is_named() {
        let bytes = sample_bytes();
        let check = |b: &[u8], what: &str| {
            let e = decode(Path::new("t.tile"), b).unwrap_err().to_string();
            assert!(e.contains(what), "{what}: {e}");
        };
        check(&bytes[..bytes.len() - 10], "truncated");
        check(&bytes[..50], "truncated");
        let mut b = bytes.clone();
        b[0] = b'X';
        check(&b, "bad magic");
        // Road data given for a tile says so (it said "bad magic", or "truncated" when short).
        for osm in [
            &b"<?xml version='1.0'?>\n<osm version='0.6'>\n</osm>\n"[..],
            b"\xef\xbb\xbf  <osm version='0.6'/>",
            b"\0\0\0\x0d\x0a\x09OSMHeader\x18\x7b",
        ] {
            check(osm, "OSM road data, not a lane tile: compile it into one");
        }
        check(b"<?xml version='1.0'?><gpx/>", "truncated");
        let mut b = bytes.clone();
        b[8] = 9;
        check(&b, "version 9");
        let mut b = bytes.clone();
        b[12..16].copy_from_slice(&0x0403_0201u32.to_le_bytes());
        check(&b, "little-endian");
        let mut b = bytes.clone();
        b[HEADER_LEN + 5] ^= 1;
        check(&b, "checksum mismatch");
        let mut b = bytes.clone();
        b.push(0);
        check(&b, "payload length");
    }

    #[test]
    fn tampering_with_a_valid_checksum_is_refused() {
        let bytes = sample_bytes();
        let layout = PayloadLayout::new(600, 20, false).unwrap();
        let check = |b: Vec<u8>, what: &str| {
            let e = decode(Path::new("t.tile"), &resealed(b))
                .unwrap_err()
                .to_string();
            assert!(e.contains(what), "{what}: {e}");
        };
        let mut b = bytes.clone();
        b[HEADER_LEN + layout.offsets.start + 4] = 0xff;
        check(b, "lane offsets");
        let mut b = bytes.clone();
        let x0 = HEADER_LEN + layout.points.start;
        b[x0..x0 + 8].copy_from_slice(&f64::NAN.to_le_bytes());
        check(b, "(NaN, 0.0) that is not finite");
        let mut b = bytes.clone();
        // x of the last point (87 m, the largest) grows a little: the bounds no longer match.
        b[HEADER_LEN + layout.points.start + 16 * 599] ^= 0x10;
        check(b, "bounds");
        let mut b = bytes.clone();
        b[HEADER_LEN + layout.info.start] = 99;
        check(b, "road class");
        let mut b = bytes.clone();
        b[230] = 1;
        check(b, "reserved");
        let mut b = bytes.clone();
        b[130] = 1;
        check(b, "signature");
        let mut b = bytes.clone();
        b[48..56].copy_from_slice(&u64::MAX.to_le_bytes());
        check(b, "point count");
        let mut b = bytes.clone();
        b[56..64].copy_from_slice(&601u64.to_le_bytes());
        check(b, "lane count");
        // Counts chosen so that naive size arithmetic wraps: refused, no panic.
        let mut b = bytes.clone();
        b[48..56].copy_from_slice(&(MAX_POINTS as u64).to_le_bytes());
        b[56..64].copy_from_slice(&(1u64 << 61).to_le_bytes());
        check(b, "lane count");
        let mut b = bytes;
        b[104..112].copy_from_slice(&u64::MAX.to_le_bytes());
        let e = decode(Path::new("t.tile"), &b).unwrap_err().to_string();
        assert!(e.contains("truncated"), "{e}");
    }

    #[test]
    fn non_regular_files_are_refused_up_front() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("fifo");
        let c_path = std::ffi::CString::new(fifo.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: a valid NUL-terminated path; mkfifo only creates a file system entry.
        assert_eq!(unsafe { libc::mkfifo(c_path.as_ptr(), 0o600) }, 0);
        for path in [dir.path(), Path::new("/dev/zero"), &fifo] {
            let e = load(path).unwrap_err();
            let refused = matches!(e, TileError::Input(InputError::NotAFile { .. }));
            assert!(refused, "{e}");
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 2000, rng_seed: proptest::test_runner::RngSeed::Fixed(3), ..ProptestConfig::default() })]
        /// Any flipped bit anywhere: the load is an error, never a panic or a map that did
        /// not pass validation.
        #[test]
        fn flipped_bytes_are_always_caught(position in 0usize..100_000, bit in 0u8..8) {
            let mut bytes = sample_bytes();
            let at = position % bytes.len();
            bytes[at] ^= 1 << bit;
            prop_assert!(decode(Path::new("t.tile"), &bytes).is_err(), "flip at byte {} went unnoticed", at);
        }
    }
}
