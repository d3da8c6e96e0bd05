//! Tile grids: a map larger than a city as square cells of one map plane, each cell a tile,
//! loaded around a corrector on demand.
//!
//! A grid is a folder: `manifest.toml` ([`Manifest`]: plane, lane geometry, cell size, margin,
//! bounds, and each cell's checksum; signed when the grid was compiled with a key,
//! [`signature`]) and `cells/<x>_<y>.tile`. Cell `(x, y)` owns the square
//! `[x s, (x + 1) s) x [y s, (y + 1) s)` of the map plane (`s` the cell size, metres) and holds
//! every lane point within `margin` of that square, as pieces of the whole map's lanes, each
//! extended by the neighbour its segments need (a piece's last point is followed by the lane's
//! next one).
//!
//! Exactness. [`assemble`] joins the pieces of any set of cells back into the lanes they came
//! from, in the whole map's order (so ties between equally distant points break as they do in
//! the whole map). Every lane point within `margin` of a loaded cell's square is then present
//! with its own segment, and a query whose nearest-neighbour disk stays within that reach gets
//! exactly the whole map's answer. The assembled map knows its reach ([`Coverage`]) and counts
//! every query that goes beyond it ([`crate::lane_map::LaneMap::uncovered_queries`]): zero means the corrections
//! equal those on the whole map, bit for bit.
//!
//! Here: the manifest and an opened grid ([`Grid`]); [`cells`] cuts a map into cells and joins
//! cells back, [`write`](mod@write) writes a grid, [`loading`] says which cells a corrector needs
//! and corrects a recorded drive on a grid.

use std::collections::{BTreeSet, HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::geo::{check_lat_lon, MapPlane, Projection};
use crate::input::InputError;
use crate::lane_geometry::{check_unmarked_offset_scale, LaneGeometry, RoadClasses, Traffic};
use crate::lane_map::{LaneMap, LaneMapError};
use crate::pose::{within_coordinate_bound, MAX_COORDINATE_M};
use crate::tile::{self, TileError, TileInfo};

pub mod cells;
pub mod loading;
pub mod signature;
pub mod write;

pub use cells::{
    assemble, cells_near, partition, partition_lanes, renumber, CellContent, Coverage, GridCell,
    OrderedLane,
};
pub use loading::{
    correct_trajectory_on_grid, CellNeeds, GridMaps, GridRun, LoadPolicy, MAX_REACH_M,
};
pub use write::{
    create_cells_dir, encode, write, write_cells, write_manifest, EncodedGrid, GridSpec, MapSummary,
};

/// The manifest's file name in a grid folder.
pub const MANIFEST: &str = "manifest.toml";
/// The format version of the manifest this build reads and writes.
pub const MANIFEST_FORMAT: u32 = 3;
/// The largest manifest this build reads (bytes): about 300,000 cells.
pub const MAX_MANIFEST_BYTES: u64 = 32 << 20;

/// A cell's index `[x, y]`: it owns `[x s, (x + 1) s) x [y s, (y + 1) s)` (metres, map plane).
pub type CellKey = [i32; 2];

/// A grid that could not be written, opened or used.
#[derive(Debug, thiserror::Error)]
pub enum GridError {
    /// The manifest could not be read or written.
    #[error(transparent)]
    Input(#[from] InputError),
    /// The manifest is not a valid grid manifest.
    #[error("{path}: {message}")]
    Manifest {
        /// The manifest.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A cell tile is damaged, or does not belong to this grid.
    #[error(transparent)]
    Tile(#[from] TileError),
    /// A cell disagrees with the manifest (another compile's cell, or a changed file).
    #[error("{path}: {message}")]
    Cell {
        /// The cell's file.
        path: PathBuf,
        /// What disagrees.
        message: String,
    },
    /// The grid's cell size or margin cannot be used.
    #[error("grid cell size {cell_size_m:?} m and margin {margin_m:?} m: the size must be 1 to {MAX_CELL_SIZE_M} m, the margin 0 to 4 cell sizes")]
    BadSpec {
        /// Cell size (metres).
        cell_size_m: f64,
        /// Margin (metres).
        margin_m: f64,
    },
    /// The lanes of the loaded cells do not make a valid map.
    #[error("assembling cells: {0}")]
    Map(#[from] LaneMapError),
}

/// One cell as the manifest lists it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CellEntry {
    /// Cell index along x.
    pub x: i32,
    /// Cell index along y.
    pub y: i32,
    /// The tile's checksum (its header's XXH3-64, 16 hex digits).
    pub checksum: String,
    /// The tile's length (bytes; at most [`tile::MAX_TILE_BYTES`], so that the lengths of every
    /// cell a manifest can list add up within a `u64`).
    pub bytes: u64,
    /// Lane points in the cell, margin included.
    pub points: u64,
}

/// What `manifest.toml` holds.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Manifest format version ([`MANIFEST_FORMAT`]).
    pub format: u32,
    /// The builder's number for this build of the map (0: none given); every cell carries the
    /// same ([`tile::set_map_version`]).
    pub map_version: u64,
    /// Side of a cell's square (metres).
    pub cell_size_m: f64,
    /// How far beyond its square a cell holds lane points (metres).
    pub margin_m: f64,
    /// The plane's projection (`kitti` or `tangent`).
    pub projection: String,
    /// The plane's origin: latitude (degrees, WGS84).
    pub origin_lat: f64,
    /// The plane's origin: longitude (degrees, WGS84).
    pub origin_lon: f64,
    /// The spacing the lanes were resampled at (metres).
    pub spacing_m: f64,
    /// The traffic side lanes were placed for (`right` or `left`).
    pub traffic: String,
    /// The road classes lanes were derived from (bit per class code, as in a tile).
    pub road_classes: u32,
    /// The unmarked-street offset scale, when lanes came from raw OSM ways.
    pub unmarked_offset_scale: Option<f64>,
    /// Lanes in the whole map.
    pub lanes: u64,
    /// Lane points in the whole map.
    pub points: u64,
    /// Bounding box of every lane point `[min x, min y, max x, max y]` (metres, map plane).
    #[serde(deserialize_with = "four_numbers")]
    pub bounds: [f64; 4],
    /// The cells that hold any lane point, in `(x, y)` order.
    pub cells: Vec<CellEntry>,
}

/// Reads an array of exactly four numbers. The TOML reader fills a `[f64; 4]` from the first
/// four numbers of a longer array and drops the rest, so a manifest's `bounds` is read as a list
/// and its length checked.
fn four_numbers<'de, D: serde::Deserializer<'de>>(reader: D) -> Result<[f64; 4], D::Error> {
    let numbers = Vec::<f64>::deserialize(reader)?;
    <[f64; 4]>::try_from(numbers.as_slice())
        .map_err(|_| serde::de::Error::invalid_length(numbers.len(), &"four numbers"))
}

/// Calls `visit` with every cell of `existing` whose square the square of half-side `half`
/// around `x` touches (metres, map plane). Walks whichever is smaller, that square's cells or
/// `existing`: a query far from the map (a pose 10,000 km away) costs what the map does, not
/// what the distance does.
fn existing_cells_near(
    existing: &HashSet<CellKey>,
    x: [f64; 2],
    half: f64,
    cell_size_m: f64,
    mut visit: impl FnMut(CellKey),
) {
    let [x0, x1] = index_range(x[0], half, cell_size_m);
    let [y0, y1] = index_range(x[1], half, cell_size_m);
    let span = |a: i32, b: i32| (i64::from(b) - i64::from(a) + 1) as u64;
    if span(x0, x1).saturating_mul(span(y0, y1)) > existing.len() as u64 {
        let inside = |k: &CellKey| (x0..=x1).contains(&k[0]) && (y0..=y1).contains(&k[1]);
        existing
            .iter()
            .filter(|k| inside(k))
            .for_each(|&k| visit(k));
    } else {
        for cx in x0..=x1 {
            for cy in y0..=y1 {
                if existing.contains(&[cx, cy]) {
                    visit([cx, cy]);
                }
            }
        }
    }
}

/// The cell indices whose squares a span `[v - half, v + half]` touches (one axis).
fn index_range(v: f64, half: f64, cell_size_m: f64) -> [i32; 2] {
    let index = |v: f64| {
        (v / cell_size_m)
            .floor()
            .clamp(i32::MIN as f64, i32::MAX as f64) as i32
    };
    [index(v - half), index(v + half)]
}

/// The largest cell (metres).
pub const MAX_CELL_SIZE_M: f64 = 100_000.0;

fn check_spec(cell_size_m: f64, margin_m: f64) -> Result<(), GridError> {
    // A margin of more than a few cells would copy every point into dozens of cells.
    let size_ok = (1.0..=MAX_CELL_SIZE_M).contains(&cell_size_m);
    if size_ok && (0.0..=4.0 * cell_size_m).contains(&margin_m) {
        Ok(())
    } else {
        Err(GridError::BadSpec {
            cell_size_m,
            margin_m,
        })
    }
}

/// An opened grid: its validated manifest; cells are read on request.
pub struct Grid {
    dir: PathBuf,
    manifest: Manifest,
    plane: MapPlane,
    geometry: LaneGeometry,
    cells: HashMap<CellKey, CellEntry>,
    existing: Arc<HashSet<CellKey>>,
    checksum: u64,
    signer: Option<[u8; 32]>,
}

impl std::fmt::Debug for Grid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Grid")
            .field("dir", &self.dir)
            .field("cells", &self.cells.len())
            .finish()
    }
}

/// The TOML reader's complaint about `text` on one line (a manifest's error goes into one log
/// line): the line it points at, quoted, and what is wrong (its own report spans several
/// lines). A complaint about the whole document (a missing field, which the reader places as an
/// empty span at its start) or about several lines names no line.
fn toml_complaint(text: &str, e: &toml::de::Error) -> String {
    let on_one_line = |span: &std::ops::Range<usize>| {
        *span != (0..0)
            && text
                .get(span.clone())
                .is_some_and(|part| !part.contains('\n'))
    };
    let at = e
        .span()
        .filter(on_one_line)
        .and_then(|span| text.get(..span.start));
    match at {
        Some(before) => {
            let number = before.matches('\n').count() + 1;
            let line = text.lines().nth(number - 1).unwrap_or_default();
            format!(
                "line {number} ({}): {}",
                crate::input::quote(line.trim()),
                e.message()
            )
        }
        None => e.message().to_string(),
    }
}

/// Whether `path` is a grid folder (a folder holding a manifest) rather than a tile file.
pub fn is_grid(path: &Path) -> bool {
    path.is_dir()
}

impl Grid {
    /// Opens the grid in folder `dir`: reads and checks its manifest (bounded, regular file).
    /// Cells are read later from the folder `dir` resolves to now (symbolic links followed).
    pub fn open(dir: &Path) -> Result<Grid, GridError> {
        let path = dir.join(MANIFEST);
        if !path.exists() {
            return Err(GridError::Manifest {
                path: dir.to_path_buf(),
                message: format!(
                    "a folder without {MANIFEST}: not a regular file (a tile), nor a grid"
                ),
            });
        }
        let bytes = crate::input::read_regular_file(&path, MAX_MANIFEST_BYTES)?;
        // The folder the path names now: a grid replaced by switching a symbolic link to a new
        // folder leaves this one reading its own cells.
        let dir = std::fs::canonicalize(dir).map_err(|source| InputError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        Self::from_manifest(&dir, &bytes)
    }

    /// The grid in folder `dir` whose manifest is `bytes` (checked as [`Self::open`] checks it).
    pub fn from_manifest(dir: &Path, bytes: &[u8]) -> Result<Grid, GridError> {
        let path = dir.join(MANIFEST);
        let bad = |message: String| GridError::Manifest {
            path: path.clone(),
            message,
        };
        let (signer, body) = signature::verify(bytes).map_err(bad)?;
        let text = std::str::from_utf8(body).map_err(|_| bad("not UTF-8 text".into()))?;
        let manifest: Manifest = toml::from_str(text).map_err(|e| bad(toml_complaint(text, &e)))?;
        if manifest.format != MANIFEST_FORMAT {
            return Err(bad(format!(
                "manifest format {}, this build reads {MANIFEST_FORMAT}: compile the grid again \
                 with this build's `lanealign-map compile --grid`",
                manifest.format
            )));
        }
        check_spec(manifest.cell_size_m, manifest.margin_m).map_err(|e| bad(e.to_string()))?;
        tile::check_map_version(manifest.map_version).map_err(|e| bad(e.to_string()))?;
        // What every cell's header must also hold (`tile::read_info`), named here rather than
        // as every cell refused for not being the grid's.
        if !tile::is_recorded_spacing(manifest.spacing_m) {
            return Err(bad(format!(
                "spacing_m = {}: a distance of 0 metres or more",
                manifest.spacing_m
            )));
        }
        if let Some(scale) = manifest.unmarked_offset_scale {
            check_unmarked_offset_scale(scale)
                .map_err(|e| bad(format!("unmarked_offset_scale: {e}")))?;
        }
        // What `inspect` prints as the map's extent: a box a tile's points could have.
        let [x0, y0, x1, y1] = manifest.bounds;
        let in_plane = manifest.bounds.iter().all(|&v| within_coordinate_bound(v));
        if !(in_plane && x0 <= x1 && y0 <= y1) {
            return Err(bad(format!(
                "bounds = {:?}: [min x, min y, max x, max y], within {MAX_COORDINATE_M:e} m",
                manifest.bounds
            )));
        }
        let projection: Projection = manifest
            .projection
            .parse()
            .map_err(|e| bad(format!("projection: {e}")))?;
        check_lat_lon(manifest.origin_lat, manifest.origin_lon)
            .map_err(|e| bad(format!("origin: {e}")))?;
        let traffic = match manifest.traffic.as_str() {
            "right" => Traffic::Right,
            "left" => Traffic::Left,
            other => return Err(bad(format!("traffic {other:?}: right or left"))),
        };
        let classes = RoadClasses::from_bits(manifest.road_classes)
            .ok_or_else(|| bad(format!("road classes {:#x}", manifest.road_classes)))?;
        let geometry = LaneGeometry {
            traffic,
            classes,
            unmarked_offset_scale: manifest.unmarked_offset_scale,
        };
        let mut cells = HashMap::with_capacity(manifest.cells.len());
        // The lane points the listed cells hold (a `u128`: 300,000 cells of up to 2^64 points).
        let mut held: u128 = 0;
        for entry in &manifest.cells {
            held += u128::from(entry.points);
            if tile::bytes_of_hex::<8>(&entry.checksum).is_none() {
                return Err(bad(format!(
                    "cell {} {}: checksum {:?} is not 16 hex digits",
                    entry.x, entry.y, entry.checksum
                )));
            }
            if entry.bytes > tile::MAX_TILE_BYTES {
                return Err(bad(format!(
                    "cell {} {}: {} bytes, longer than a tile may be ({} bytes)",
                    entry.x,
                    entry.y,
                    entry.bytes,
                    tile::MAX_TILE_BYTES
                )));
            }
            if cells.insert([entry.x, entry.y], entry.clone()).is_some() {
                return Err(bad(format!("cell {} {} is listed twice", entry.x, entry.y)));
            }
        }
        if cells.is_empty() {
            return Err(bad("the grid has no cell".into()));
        }
        // What `inspect` and the daemon report of the whole map: every lane has a point, and
        // every point lies in the square (margin included) of the cell that owns it.
        if !(1..=manifest.points).contains(&manifest.lanes) || u128::from(manifest.points) > held {
            return Err(bad(format!(
                "lanes = {} and points = {}, its cells hold {held} points: a map of at least one \
                 lane, each with a point, every point in a cell",
                manifest.lanes, manifest.points
            )));
        }
        let existing = Arc::new(cells.keys().copied().collect());
        Ok(Grid {
            checksum: xxhash_rust::xxh3::xxh3_64(bytes),
            signer,
            dir: dir.to_path_buf(),
            plane: MapPlane::new(projection, manifest.origin_lat, manifest.origin_lon),
            geometry,
            manifest,
            cells,
            existing,
        })
    }

    /// XXH3-64 of the manifest's bytes: identifies the grid (each cell's checksum is in it).
    pub fn checksum(&self) -> u64 {
        self.checksum
    }

    /// The ed25519 public key whose signature the manifest carries, verified (`None`: unsigned;
    /// each cell's own signature is verified as the cell is loaded).
    pub fn signer(&self) -> Option<[u8; 32]> {
        self.signer
    }

    /// What a tile of the whole grid would say about itself (counts, bounds and total bytes
    /// from the manifest, [`Self::checksum`] as its checksum, the manifest's signer as its
    /// signer).
    pub fn info(&self) -> TileInfo {
        let m = &self.manifest;
        TileInfo {
            plane: self.plane,
            spacing_m: m.spacing_m,
            geometry: self.geometry,
            points: m.points,
            lanes: m.lanes,
            bounds: m.bounds,
            payload_len: m.cells.iter().map(|c| c.bytes).sum(),
            checksum: self.checksum,
            signer: self.signer,
            map_version: m.map_version,
            cell: None,
        }
    }

    /// The manifest.
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// The map plane every cell is in.
    pub fn plane(&self) -> MapPlane {
        self.plane
    }

    /// How the lanes were derived.
    pub fn geometry(&self) -> LaneGeometry {
        self.geometry
    }

    /// Every cell that holds lanes.
    pub fn cells(&self) -> impl Iterator<Item = CellKey> + '_ {
        self.manifest.cells.iter().map(|e| [e.x, e.y])
    }

    /// The file of cell `key`.
    pub fn cell_path(&self, key: CellKey) -> PathBuf {
        self.dir.join("cells").join(cell_file_name(key))
    }

    /// Reads and validates cell `key`: the tile must be valid, match the manifest's checksum
    /// and length, and share the grid's plane, spacing, geometry and cell square. The cell owns
    /// its data: the file can change afterwards without effect.
    pub fn load_cell(&self, key: CellKey) -> Result<GridCell, GridError> {
        let path = self.cell_path(key);
        let bad = |message: String| GridError::Cell {
            path: path.clone(),
            message,
        };
        if !self.cells.contains_key(&key) {
            return Err(bad("not in the manifest".into()));
        }
        let bytes = crate::input::read_regular_file(&path, tile::MAX_TILE_BYTES)?;
        self.cell_from_bytes(key, &bytes)
    }

    /// The map of cells `keys`, each loaded (and checked) from disk and joined (see
    /// [`assemble`]): for a map used once, where nothing is worth caching.
    pub fn map_of(&self, keys: impl IntoIterator<Item = CellKey>) -> Result<LaneMap, GridError> {
        let cells = keys
            .into_iter()
            .map(|key| self.load_cell(key).map(Arc::new))
            .collect::<Result<Vec<_>, _>>()?;
        assemble(self, &cells)
    }

    /// Cell `key` from its tile bytes, checked as [`Self::load_cell`] checks a file.
    pub fn cell_from_bytes(&self, key: CellKey, bytes: &[u8]) -> Result<GridCell, GridError> {
        let path = self.cell_path(key);
        let bad = |message: String| GridError::Cell {
            path: path.clone(),
            message,
        };
        let entry = self
            .cells
            .get(&key)
            .ok_or_else(|| bad("not in the manifest".into()))?;
        let (pieces, info, origins) = tile::decode_cell(&path, bytes)?;
        let square = self.square(key);
        if format!("{:016x}", info.checksum) != entry.checksum || bytes.len() as u64 != entry.bytes
        {
            return Err(bad(format!(
                "checksum {:016x} and {} bytes, the manifest says {} and {} bytes: the cell is not this grid's",
                info.checksum,
                bytes.len(),
                entry.checksum,
                entry.bytes
            )));
        }
        self.check_info(&info, square, entry).map_err(bad)?;
        if let Some(&[lane, _]) = origins
            .iter()
            .find(|o| u64::from(o[0]) >= self.manifest.lanes)
        {
            return Err(bad(format!(
                "a piece of lane {lane}, the grid has {} lanes",
                self.manifest.lanes
            )));
        }
        Ok(GridCell {
            key,
            pieces,
            origins,
            signer: info.signer,
        })
    }

    fn check_info(
        &self,
        info: &TileInfo,
        square: [f64; 4],
        entry: &CellEntry,
    ) -> Result<(), String> {
        if info.plane != self.plane
            || info.spacing_m.to_bits() != self.manifest.spacing_m.to_bits()
            || info.geometry != self.geometry
        {
            return Err("its plane, spacing or lane geometry is not the grid's".into());
        }
        if info.map_version != self.manifest.map_version {
            return Err(format!(
                "map version {}, the manifest's is {}: the cell is another build's",
                info.map_version, self.manifest.map_version
            ));
        }
        if info.cell != Some(square) {
            return Err(format!(
                "its square {:?} is not the grid's {square:?} for this cell",
                info.cell
            ));
        }
        if info.points != entry.points {
            return Err(format!(
                "{} lane points, the manifest says {}",
                info.points, entry.points
            ));
        }
        // Every point of a cell is one of the whole map's.
        let [x0, y0, x1, y1] = self.manifest.bounds;
        let b = info.bounds;
        if !(b[0] >= x0 && b[1] >= y0 && b[2] <= x1 && b[3] <= y1) {
            return Err(format!(
                "its points reach {b:?}, beyond the grid's bounds {:?}",
                self.manifest.bounds
            ));
        }
        Ok(())
    }

    /// Cell `key`'s own square `[min x, min y, max x, max y]` (metres, map plane).
    pub fn square(&self, key: CellKey) -> [f64; 4] {
        square_of(key, self.manifest.cell_size_m)
    }

    /// The cells (that hold lanes) a corrector with this window needs under `policy`: within
    /// `radius_m` of any window pose (oldest first; metres, map plane) and of the road `ahead_m`
    /// beyond the newest along its direction of travel.
    pub fn wanted(&self, window: &[[f64; 2]], policy: &LoadPolicy) -> BTreeSet<CellKey> {
        let step = self.manifest.cell_size_m / 4.0;
        let radius = policy.radius_m + step;
        let mut out = BTreeSet::new();
        let mut add = |p: [f64; 2]| {
            existing_cells_near(
                &self.existing,
                p,
                radius,
                self.manifest.cell_size_m,
                |key| {
                    out.insert(key);
                },
            );
        };
        let mut last: Option<[f64; 2]> = None;
        for (i, &p) in window.iter().enumerate() {
            let far = last.is_none_or(|q| distance(p, q) > step);
            if far || i + 1 == window.len() {
                add(p);
                last = Some(p);
            }
        }
        if let [.., before, newest] = window {
            let d = distance(*before, *newest);
            if d > 0.0 {
                let dir = [(newest[0] - before[0]) / d, (newest[1] - before[1]) / d];
                let samples = (policy.ahead_m / step).ceil() as usize;
                for k in 1..=samples {
                    let t = (k as f64 * step).min(policy.ahead_m);
                    add([newest[0] + t * dir[0], newest[1] + t * dir[1]]);
                }
            }
        }
        out
    }
}

fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

/// Cell `key`'s own square `[min x, min y, max x, max y]` in a grid of `cell_size_m` cells.
fn square_of(key: CellKey, cell_size_m: f64) -> [f64; 4] {
    let s = cell_size_m;
    [
        f64::from(key[0]) * s,
        f64::from(key[1]) * s,
        (f64::from(key[0]) + 1.0) * s,
        (f64::from(key[1]) + 1.0) * s,
    ]
}

/// The file name of cell `key` inside the grid's `cells` folder.
pub fn cell_file_name(key: CellKey) -> String {
    format!("{}_{}.tile", key[0], key[1])
}

#[cfg(test)]
mod tests {
    use super::cells::pieces_of;
    use super::*;
    use crate::lane_geometry::LaneInfo;
    use crate::lane_map::{Lane, LaneMap};

    /// A cell size or margin out of range is quoted as written (`1e300`, not in 301 digits).
    #[test]
    fn a_bad_cell_size_is_quoted_as_written() {
        let refused = check_spec(1e300, 50.0).map_err(|e| e.to_string());
        assert_eq!(
            refused,
            Err(format!(
                "grid cell size 1e300 m and margin 50.0 m: the size must be 1 to \
                 {MAX_CELL_SIZE_M} m, the margin 0 to 4 cell sizes"
            ))
        );
    }

    #[test]
    fn pieces_keep_the_segment_neighbours() {
        assert_eq!(pieces_of(&[2, 3, 4], 10), vec![[1, 6]]);
        assert_eq!(pieces_of(&[0, 1, 6, 7], 10), vec![[0, 3], [5, 9]]);
        assert_eq!(pieces_of(&[0, 1, 5, 6], 10), vec![[0, 8]]);
        assert_eq!(pieces_of(&[9], 10), vec![[7, 9]]);
        assert_eq!(pieces_of(&[0], 1), vec![[0, 0]]);
        assert_eq!(pieces_of(&[7, 8, 9], 10), vec![[6, 9]]);
    }

    /// A town of lanes crossing many cells, with shared end points (ties), lanes of one and
    /// two points, and a winding road (its segments have chord errors).
    fn town() -> LaneMap {
        let mut lanes = Vec::new();
        let winding: Vec<[f64; 2]> = (0..90)
            .map(|i| [i as f64 * 4.9 - 20.0, 210.0 + 25.0 * (i as f64 * 0.3).sin()])
            .collect();
        lanes.push(Lane::new(600, winding));
        for r in 0..12 {
            let y = r as f64 * 37.5;
            let east: Vec<[f64; 2]> = (0..90).map(|i| [i as f64 * 4.9 - 20.0, y]).collect();
            let mut west = east.clone();
            west.reverse();
            west.iter_mut().for_each(|p| p[1] += 3.5);
            lanes.push(Lane::new(2 * r, east));
            lanes.push(Lane::new(2 * r + 1, west));
            let north: Vec<[f64; 2]> = (0..100)
                .map(|i| [r as f64 * 41.0, i as f64 * 4.7 - 30.0])
                .collect();
            lanes.push(Lane {
                id: 100 + r,
                info: LaneInfo::new(crate::lane_geometry::RoadClass::Primary, 0),
                points: north,
            });
        }
        lanes.push(Lane::new(500, vec![[100.0, 100.0]]));
        lanes.push(Lane::new(501, vec![[150.0, 150.0], [152.0, 150.0]]));
        LaneMap::new(&lanes).unwrap()
    }

    fn grid_of(map: &LaneMap, dir: &Path, cell: f64, margin: f64) -> Grid {
        signed_grid_of(map, dir, cell, margin, None)
    }

    fn signed_grid_of(
        map: &LaneMap,
        dir: &Path,
        cell: f64,
        margin: f64,
        sign: Option<&tile::SigningKey>,
    ) -> Grid {
        write_versioned(map, dir, [cell, margin], sign, 0).unwrap();
        Grid::open(dir).unwrap()
    }

    /// Writes `map` as a grid of `[cell size, margin]` (metres) in the tests' plane, signed with
    /// `sign`, as build `map_version`.
    fn write_versioned(
        map: &LaneMap,
        dir: &Path,
        [cell, margin]: [f64; 2],
        sign: Option<&tile::SigningKey>,
        map_version: u64,
    ) -> Result<Manifest, GridError> {
        let plane = MapPlane::new(Projection::Tangent, 48.98, 8.39);
        let spec = GridSpec {
            plane: &plane,
            spacing_m: 3.0,
            geometry: &LaneGeometry::default(),
            cell_size_m: cell,
            margin_m: margin,
            sign,
            map_version,
        };
        write(dir, map, &spec, 2)
    }

    /// The manifest and every cell carry the build's map version; a manifest edited to claim
    /// another build is refused at open when signed, and at its first cell when not.
    #[test]
    fn a_manifest_claiming_another_build_is_refused() {
        let key = tile::SigningKey::from_bytes(&[9; 32]);
        for sign in [None, Some(&key)] {
            let dir = tempfile::tempdir().unwrap();
            write_versioned(&town(), dir.path(), [50.0, 10.0], sign, 5).unwrap();
            let grid = Grid::open(dir.path()).unwrap();
            assert_eq!(grid.info().map_version, 5);
            let first = grid.cells().next().unwrap();
            assert!(grid.load_cell(first).is_ok());
            let cell = std::fs::read(grid.cell_path(first)).unwrap();
            assert_eq!(
                tile::read_info(Path::new("c"), &cell).unwrap().map_version,
                5
            );
            let path = dir.path().join(MANIFEST);
            let text = std::fs::read_to_string(&path).unwrap();
            assert!(text.contains("\nmap_version = 5\n"), "{text}");
            std::fs::write(&path, text.replace("map_version = 5", "map_version = 6")).unwrap();
            match sign {
                Some(_) => {
                    let e = Grid::open(dir.path()).unwrap_err().to_string();
                    assert!(e.contains("signature"), "{e}");
                }
                None => {
                    let grid = Grid::open(dir.path()).unwrap();
                    assert_eq!(grid.info().map_version, 6);
                    let Err(e) = grid.load_cell(first) else {
                        panic!("a cell of version 5 under a manifest of version 6 was loaded");
                    };
                    let e = e.to_string();
                    assert!(e.contains("map version 5, the manifest's is 6"), "{e}");
                }
            }
        }
        let dir = tempfile::tempdir().unwrap();
        let beyond = tile::MAX_MAP_VERSION + 1;
        let e = write_versioned(&town(), dir.path(), [50.0, 10.0], None, beyond)
            .unwrap_err()
            .to_string();
        assert!(e.contains("map version"), "{e}");
        assert!(!dir.path().join("cells").exists(), "refused before writing");
    }

    /// A grid compiled with a key signs its manifest as well as its cells, and an edit of the
    /// manifest is refused at open. Unsigned, a manifest edited to leave a cell out opened as
    /// a grid without that cell's lanes (when the cell held too few points for the totals).
    #[test]
    fn a_signed_manifest_refuses_a_cell_left_out() {
        let dir = tempfile::tempdir().unwrap();
        let key = tile::SigningKey::from_bytes(&[9; 32]);
        let grid = signed_grid_of(&town(), dir.path(), 50.0, 10.0, Some(&key));
        let signer = Some(key.verifying_key().to_bytes());
        assert_eq!((grid.signer(), grid.info().signer), (signer, signer));
        for cell in grid.cells() {
            assert_eq!(grid.load_cell(cell).unwrap().signer(), signer);
        }
        let path = dir.path().join(MANIFEST);
        let good = std::fs::read_to_string(&path).unwrap();
        // The cell holding the fewest points left out: its `[[cells]]` table cut.
        let fewest = grid
            .manifest()
            .cells
            .iter()
            .min_by_key(|c| c.points)
            .unwrap();
        let at = good
            .find(&format!("checksum = \"{}\"", fewest.checksum))
            .unwrap();
        let start = good[..at].rfind("[[cells]]").unwrap();
        let end = good[at..].find("[[cells]]").map_or(good.len(), |n| at + n);
        let cut = format!("{}{}", &good[..start], &good[end..]);
        std::fs::write(&path, &cut).unwrap();
        let e = Grid::open(dir.path()).err().unwrap().to_string();
        assert!(
            e.contains("the signature does not match the manifest"),
            "{e}"
        );
        // The same edit to the unsigned manifest passes every other check.
        let (_, unsigned) = cut.split_at(cut.find("format = ").unwrap());
        std::fs::write(&path, unsigned).unwrap();
        let opened = Grid::open(dir.path()).unwrap();
        assert_eq!(opened.signer(), None);
        assert_eq!(opened.cells().count() + 1, grid.cells().count());
    }

    /// The map of the cells within `radius_m` of `x`; `None` when no cell is near.
    fn around(grid: &Grid, x: [f64; 2], radius_m: f64) -> Option<LaneMap> {
        let policy = LoadPolicy {
            radius_m,
            ahead_m: 0.0,
        };
        let wanted = grid.wanted(&[x], &policy);
        (!wanted.is_empty()).then(|| grid.map_of(wanted).unwrap())
    }

    #[test]
    fn all_cells_assemble_into_the_whole_map() {
        let dir = tempfile::tempdir().unwrap();
        let map = town();
        let grid = grid_of(&map, dir.path(), 50.0, 10.0);
        let whole = grid.map_of(grid.cells()).unwrap();
        assert_eq!(whole, map);
    }

    /// Every nearest-neighbour query the coverage vouches for equals the whole map's, on
    /// partial sets of cells.
    #[test]
    fn covered_queries_equal_the_whole_map() {
        let dir = tempfile::tempdir().unwrap();
        let map = town();
        let grid = grid_of(&map, dir.path(), 60.0, 15.0);
        let mut rng = 12345u64;
        let mut next = move || {
            rng = rng
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (rng >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut checked, mut vouched) = (0, 0);
        for _ in 0..40 {
            let centre = [next() * 450.0 - 20.0, next() * 450.0 - 30.0];
            let Some(part) = around(&grid, centre, next() * 80.0) else {
                continue;
            };
            for _ in 0..50 {
                let x = [
                    centre[0] + next() * 120.0 - 60.0,
                    centre[1] + next() * 120.0 - 60.0,
                ];
                let n = 1 + (next() * 12.0) as usize;
                let (mut a, mut b) = (Vec::new(), Vec::new());
                let before = part.uncovered_queries();
                part.nearest(x, n, &mut a);
                checked += 1;
                if part.uncovered_queries() == before {
                    vouched += 1;
                    map.nearest(x, n, &mut b);
                    let global = |c: &Vec<(f64, u32)>, m: &LaneMap| -> Vec<(u64, [u64; 2])> {
                        c.iter()
                            .map(|&(_, j)| {
                                let p = m.points()[j as usize];
                                (m.lane_ids()[m.lane_of(j)], [p[0].to_bits(), p[1].to_bits()])
                            })
                            .collect()
                    };
                    assert_eq!(global(&a, &part), global(&b, &map), "query {x:?} n {n}");
                    let seg = |c: &Vec<(f64, u32)>, m: &LaneMap| -> Vec<_> {
                        c.iter()
                            .map(|&(_, j)| (m.segment_of(j), m.chord_error_m(j).to_bits()))
                            .collect()
                    };
                    assert_eq!(seg(&a, &part), seg(&b, &map), "query {x:?} n {n}");
                }
            }
        }
        assert!(vouched > checked / 2, "{vouched} of {checked} vouched for");
        assert!(vouched < checked, "no query went past the loaded cells");
    }

    /// Every point a loaded cell holds as its own (within the margin of its square) has the
    /// chord error it has in the whole map: its pieces carry the neighbours of its segment's turns.
    #[test]
    fn held_points_have_the_whole_maps_chord_errors() {
        let dir = tempfile::tempdir().unwrap();
        let margin = 10.0;
        let grid = grid_of(&town(), dir.path(), 60.0, margin);
        let all = grid.map_of(grid.cells()).unwrap();
        let (mut checked, mut curved) = (0, 0);
        for x in [0.0, 55.0, 130.0, 200.0, 310.0, 390.0] {
            let part = around(&grid, [x, 210.0], 40.0).unwrap();
            let loaded: Vec<[f64; 4]> = part
                .coverage()
                .unwrap()
                .loaded()
                .iter()
                .map(|&key| grid.square(key))
                .collect();
            for j in 0..part.len() as u32 {
                let p = part.points()[j as usize];
                let held = loaded.iter().any(|q| {
                    p[0] >= q[0] - margin
                        && p[0] <= q[2] + margin
                        && p[1] >= q[1] - margin
                        && p[1] <= q[3] + margin
                });
                if held {
                    let k = renumber(&part, &all, j).unwrap();
                    assert_eq!(
                        part.chord_error_m(j).to_bits(),
                        all.chord_error_m(k).to_bits(),
                        "point {p:?}"
                    );
                    checked += 1;
                    curved += usize::from(all.chord_error_m(k) > 0.0);
                }
            }
        }
        assert!(
            checked > 500 && curved > 30,
            "{checked} checked, {curved} curved"
        );
    }

    /// A point renumbered from one partial map into another is the same point of the same lane,
    /// and points the other map lacks have no number there.
    #[test]
    fn renumbering_finds_the_same_point() {
        let dir = tempfile::tempdir().unwrap();
        let grid = grid_of(&town(), dir.path(), 60.0, 10.0);
        let part = |x: f64| around(&grid, [x, 200.0], 100.0).unwrap();
        let (a, b) = (part(100.0), part(200.0));
        let (mut found, mut missing) = (0, 0);
        for j in 0..a.len() as u32 {
            match renumber(&a, &b, j) {
                Some(k) => {
                    found += 1;
                    assert_eq!(a.points()[j as usize], b.points()[k as usize]);
                    assert_eq!(a.lane_ids()[a.lane_of(j)], b.lane_ids()[b.lane_of(k)]);
                    assert_eq!(a.segment_of(j).is_some(), b.segment_of(k).is_some());
                }
                None => missing += 1,
            }
        }
        assert!(
            found > 100 && missing > 100,
            "{found} found, {missing} missing"
        );
        let whole = town();
        assert_eq!(
            renumber(&whole, &a, 0),
            None,
            "a whole map has no grid numbering"
        );
    }

    /// A pose 10,000 km from the map, or a query reaching that far, costs what the map does:
    /// it neither hangs walking empty cells nor claims coverage it does not have.
    #[test]
    fn far_queries_are_bounded_by_the_map() {
        let dir = tempfile::tempdir().unwrap();
        let grid = grid_of(&town(), dir.path(), 50.0, 10.0);
        let policy = LoadPolicy {
            radius_m: MAX_REACH_M,
            ahead_m: MAX_REACH_M,
        };
        let far = [1e7, -1e7];
        assert!(grid
            .wanted(&[far, [far[0] + 1.0, far[1]]], &policy)
            .is_empty());
        let part = around(&grid, [100.0, 100.0], 10.0).unwrap();
        let coverage = part.coverage().unwrap();
        assert!(
            !coverage.covers(far, 1.5e7),
            "reaches every cell, most not loaded"
        );
        assert!(coverage.covers(far, 1.0), "an empty stretch of plane");
        assert!(coverage.covers([100.0, 100.0], 5.0));
        assert!(grid
            .map_of(grid.cells())
            .unwrap()
            .coverage()
            .unwrap()
            .covers(far, f64::INFINITY));
        for (size, margin) in [
            (0.5, 0.0),
            (2e5, 0.0),
            (50.0, 201.0),
            (50.0, -1.0),
            (f64::NAN, 1.0),
        ] {
            assert!(partition(&town(), size, margin).is_err(), "{size} {margin}");
        }
        assert!(LoadPolicy {
            radius_m: 1e300,
            ahead_m: 0.0
        }
        .validate()
        .is_err());
    }

    #[test]
    fn a_cell_from_another_grid_is_refused() {
        let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
        let map = town();
        let grid_a = grid_of(&map, a.path(), 50.0, 10.0);
        grid_of(&map, b.path(), 50.0, 20.0);
        let key = [2, 2];
        std::fs::copy(
            b.path().join("cells").join(cell_file_name(key)),
            grid_a.cell_path(key),
        )
        .unwrap();
        let e = grid_a.load_cell(key).err().unwrap().to_string();
        assert!(e.contains("not this grid's"), "{e}");
        let whole = tile::encode(&map, &grid_a.plane(), 3.0, &LaneGeometry::default());
        let e = tile::decode_cell(Path::new("w.tile"), &whole)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("grid cell was expected"), "{e}");
        let cell = std::fs::read(grid_a.cell_path(grid_a.cells().nth(1).unwrap())).unwrap();
        let e = tile::decode(Path::new("c.tile"), &cell)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("give the grid's folder"), "{e}");
    }

    #[test]
    fn a_manifest_too_large_to_read_is_not_written() {
        let dir = tempfile::tempdir().unwrap();
        let plane = MapPlane::new(Projection::Tangent, 48.98, 8.39);
        let spec = GridSpec {
            plane: &plane,
            spacing_m: 3.0,
            geometry: &LaneGeometry::default(),
            cell_size_m: 100.0,
            margin_m: 10.0,
            sign: None,
            map_version: 0,
        };
        let cells = |n: i32| -> Vec<CellEntry> {
            (0..n)
                .map(|k| CellEntry {
                    x: k % 1000,
                    y: k / 1000,
                    checksum: format!("{:016x}", u64::MAX - k as u64),
                    bytes: 1 << 20,
                    points: 1 << 20,
                })
                .collect()
        };
        let mut summary = MapSummary::empty();
        summary.add(&[[0.0, 0.0], [1.0, 1.0]]);
        // About 100 bytes a cell: 200,000 cells fit, 400,000 do not.
        let written = write_manifest(dir.path(), &spec, &summary, cells(200_000)).unwrap();
        assert_eq!(written.cells.len(), 200_000);
        std::fs::remove_file(dir.path().join(MANIFEST)).unwrap();
        let e = write_manifest(dir.path(), &spec, &summary, cells(400_000))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("400000 cells") && e.contains("larger cells"),
            "{e}"
        );
        assert!(!dir.path().join(MANIFEST).exists());
    }

    #[test]
    fn bad_manifests_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        grid_of(&town(), dir.path(), 50.0, 10.0);
        let path = dir.path().join(MANIFEST);
        let good = std::fs::read_to_string(&path).unwrap();
        for (from, to, what) in [
            ("cell_size_m = 50.0", "cell_size_m = 0.0", "cell size"),
            ("format = 3", "format = 7", "format 7"),
            (
                "map_version = 0",
                "map_version = -1",
                "line 2 (map_version = -1): invalid value: integer `-1`, expected u64",
            ),
            ("map_version = 0", "map_version = 1.5", "expected u64"),
            (
                "map_version = 0\n",
                "",
                "manifest.toml: missing field `map_version`",
            ),
            ("traffic = \"right\"", "traffic = \"up\"", "traffic"),
            (
                "margin_m = 10.0",
                "margin_m = 10.0\nextra = 1",
                "unknown field",
            ),
            ("spacing_m = 3.0", "spacing_m = nan", "spacing_m = NaN"),
            ("spacing_m = 3.0", "spacing_m = -3.0", "spacing_m = -3"),
            (
                "bounds = [-20.0,",
                "bounds = [nan,",
                "bounds = [NaN, -30.0, ",
            ),
            (
                "bounds = [-20.0,",
                "bounds = [-1e8,",
                "bounds = [-100000000.0, ",
            ),
            ("bounds = [-20.0,", "bounds = [500.0,", "bounds = [500.0, "),
            (
                "bounds = [-20.0, -30.0, 451.0,",
                "bounds = [-20.0, -30.0, 451.0, 452.0,",
                "invalid length 5, expected four numbers",
            ),
            (
                "unmarked_offset_scale = 0.5",
                "unmarked_offset_scale = inf",
                "unmarked_offset_scale: the unmarked-street offset scale inf is outside [0, 2]",
            ),
        ] {
            std::fs::write(&path, good.replacen(from, to, 1)).unwrap();
            let e = Grid::open(dir.path()).err().unwrap().to_string();
            assert!(e.contains(what), "{what}: {e}");
        }
        // A checksum of 16 characters that are not all hex digits: `u64::from_str_radix` took a
        // leading '+', and such a manifest opened (its cell then failed to load).
        let at = good.find("checksum = \"").unwrap() + "checksum = \"".len();
        let signed_digit = format!("{}+{}", &good[..at], &good[at + 1..]);
        std::fs::write(&path, signed_digit).unwrap();
        let e = Grid::open(dir.path()).err().unwrap().to_string();
        assert!(e.contains("is not 16 hex digits"), "{e}");
    }

    /// A manifest's counts are what `inspect` and the daemon report of the map: a total its
    /// cells cannot hold, or a cell's count its tile does not have, is refused, not reported.
    #[test]
    fn counts_the_cells_do_not_hold_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let map = town();
        grid_of(&map, dir.path(), 50.0, 10.0);
        let path = dir.path().join(MANIFEST);
        let good = std::fs::read_to_string(&path).unwrap();
        let (lanes, points) = (map.lane_count(), map.len());
        for (from, to) in [
            (format!("lanes = {lanes}\n"), "lanes = 0\n".to_string()),
            (
                format!("lanes = {lanes}\n"),
                format!("lanes = {}\n", points + 1),
            ),
            (
                format!("\npoints = {points}\n"),
                format!("\npoints = {}\n", u64::MAX),
            ),
        ] {
            assert!(good.contains(&from), "{from}");
            std::fs::write(&path, good.replacen(&from, &to, 1)).unwrap();
            let e = Grid::open(dir.path()).err().unwrap().to_string();
            assert!(e.contains("its cells hold"), "{to}: {e}");
        }
        std::fs::write(&path, &good).unwrap();
        let entry = Grid::open(dir.path()).unwrap().manifest().cells[0].clone();
        let line = format!("points = {}\n", entry.points);
        let at = good
            .find(&format!("checksum = \"{}\"", entry.checksum))
            .unwrap();
        let from = at + good[at..].find(&line).unwrap();
        let crafted = format!(
            "{}points = {}\n{}",
            &good[..from],
            entry.points + 1,
            &good[from + line.len()..]
        );
        std::fs::write(&path, crafted).unwrap();
        let grid = Grid::open(dir.path()).unwrap();
        let e = grid
            .load_cell([entry.x, entry.y])
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("lane points, the manifest says"), "{e}");
        assert!(grid.map_of(grid.cells().skip(1)).is_ok());
    }

    /// A manifest whose bounds do not hold a cell's points is refused at that cell, which
    /// `inspect` loads with every other.
    #[test]
    fn a_cell_beyond_the_manifests_bounds_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let grid = grid_of(&town(), dir.path(), 50.0, 10.0);
        let farthest_x: Vec<(CellKey, f64)> = grid
            .cells()
            .map(|key| {
                let cell = grid.load_cell(key).unwrap();
                (key, tile::bounds(cell.pieces.points())[2])
            })
            .collect();
        let path = dir.path().join(MANIFEST);
        let good = std::fs::read_to_string(&path).unwrap();
        let (from, to) = (
            "bounds = [-20.0, -30.0, 451.0,",
            "bounds = [-20.0, -30.0, 300.0,",
        );
        assert!(good.contains(from), "{good}");
        std::fs::write(&path, good.replacen(from, to, 1)).unwrap();
        let grid = Grid::open(dir.path()).unwrap();
        for &(key, x) in &farthest_x {
            match grid.load_cell(key) {
                Ok(_) => assert!(x <= 300.0, "{key:?} reaches {x} m"),
                Err(e) => assert!(
                    x > 300.0 && e.to_string().contains("beyond the grid's bounds"),
                    "{key:?} reaches {x} m: {e}"
                ),
            }
        }
        assert!(farthest_x.iter().any(|&(_, x)| x > 300.0));
        assert!(farthest_x.iter().any(|&(_, x)| x <= 300.0));
    }

    /// The daemon sums the listed cells' lengths when it starts on a grid (`Grid::info`), and
    /// loads only the cells near its sources: a manifest listing far cells of 2^64 - 1 bytes
    /// each overflowed the sum, and the daemon panicked at every start.
    #[test]
    fn a_cell_longer_than_a_tile_may_be_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        grid_of(&town(), dir.path(), 50.0, 10.0);
        let path = dir.path().join(MANIFEST);
        let good = std::fs::read_to_string(&path).unwrap();
        let crafted: String = good
            .lines()
            .map(|line| match line.starts_with("bytes = ") {
                true => format!("bytes = {}\n", u64::MAX),
                false => format!("{line}\n"),
            })
            .collect();
        assert!(crafted.matches(&u64::MAX.to_string()).count() >= 2);
        std::fs::write(&path, crafted).unwrap();
        match Grid::open(dir.path()) {
            Ok(grid) => panic!("opened, with {} bytes of cells", grid.info().payload_len),
            Err(e) => assert!(e.to_string().contains("longer than a tile"), "{e}"),
        }
    }
}
