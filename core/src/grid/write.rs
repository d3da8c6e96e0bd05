//! Writing a map as a grid: every cell's tile and the manifest, to a folder or in memory.

use std::path::{Path, PathBuf};

use crate::geo::MapPlane;
use crate::input::InputError;
use crate::lane_geometry::{LaneGeometry, Traffic};
use crate::lane_map::LaneMap;
use crate::tile::{self, SigningKey};

use super::{
    cell_file_name, partition, square_of, CellContent, CellEntry, CellKey, GridError, Manifest,
    MANIFEST, MANIFEST_FORMAT, MAX_MANIFEST_BYTES,
};

/// What [`write`](fn@write) needs besides the map: its plane, how it was made, and the grid.
pub struct GridSpec<'a> {
    /// The plane of the map.
    pub plane: &'a MapPlane,
    /// The spacing the lanes were resampled at (metres).
    pub spacing_m: f64,
    /// How the lanes were derived.
    pub geometry: &'a LaneGeometry,
    /// Side of a cell's square (metres).
    pub cell_size_m: f64,
    /// How far beyond its square a cell holds lane points (metres).
    pub margin_m: f64,
    /// Sign every cell, and the manifest, with this key.
    pub sign: Option<&'a SigningKey>,
    /// The builder's number for this build of the map, recorded in the manifest and every cell
    /// (0: none given; at most [`tile::MAX_MAP_VERSION`]).
    pub map_version: u64,
}

/// Writes `map` as a grid into folder `dir`: every cell, then the manifest (each atomically;
/// the manifest last, so that a reader never sees a manifest naming a cell not yet written).
/// Cells are encoded in parallel by the caller's choice of `encode_threads` (at least 1).
pub fn write(
    dir: &Path,
    map: &LaneMap,
    spec: &GridSpec,
    encode_threads: usize,
) -> Result<Manifest, GridError> {
    tile::check_map_version(spec.map_version)?;
    let cells = partition(map, spec.cell_size_m, spec.margin_m)?;
    let cells_dir = create_cells_dir(dir)?;
    let chunk = cells.len().div_ceil(encode_threads.max(1)).max(1);
    let entries: Vec<Result<Vec<CellEntry>, GridError>> = std::thread::scope(|scope| {
        let handles: Vec<_> = cells
            .chunks(chunk)
            .map(|part| scope.spawn(|| write_cells(&cells_dir, part, spec)))
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().unwrap_or_else(|p| std::panic::resume_unwind(p)))
            .collect()
    });
    let mut cell_entries = Vec::with_capacity(cells.len());
    for part in entries {
        cell_entries.extend(part?);
    }
    write_manifest(dir, spec, &MapSummary::of(map), cell_entries)
}

/// Creates `dir/cells` (and `dir`) for [`write_cells`]; returns its path.
pub fn create_cells_dir(dir: &Path) -> Result<PathBuf, GridError> {
    let cells_dir = dir.join("cells");
    std::fs::create_dir_all(&cells_dir).map_err(|source| InputError::Io {
        path: cells_dir.clone(),
        source,
    })?;
    Ok(cells_dir)
}

/// Encodes `cells` and writes each (atomically) into `cells_dir`; returns their manifest
/// entries in the same order.
pub fn write_cells(
    cells_dir: &Path,
    cells: &[CellContent],
    spec: &GridSpec,
) -> Result<Vec<CellEntry>, GridError> {
    cells
        .iter()
        .map(|cell| {
            let (entry, bytes) = encode_one(cell, spec)?;
            tile::write_bytes(&cells_dir.join(cell_file_name(cell.key)), &bytes)?;
            Ok(entry)
        })
        .collect()
}

/// Writes the manifest of a map summed up by `summary` and cut into the cells `cells` (in any
/// order) into folder `dir`, atomically, once every cell is written (signed with `spec.sign`,
/// [`super::signature`]); returns it.
pub fn write_manifest(
    dir: &Path,
    spec: &GridSpec,
    summary: &MapSummary,
    mut cells: Vec<CellEntry>,
) -> Result<Manifest, GridError> {
    cells.sort_by_key(|c| (c.x, c.y));
    let manifest = manifest_of(summary, spec, cells);
    let text = toml::to_string(&manifest).map_err(|e| GridError::Manifest {
        path: dir.join(MANIFEST),
        message: e.to_string(),
    })?;
    let text = match spec.sign {
        Some(key) => super::signature::sign(&text, key),
        None => text,
    };
    if text.len() as u64 > MAX_MANIFEST_BYTES {
        return Err(GridError::Manifest {
            path: dir.join(MANIFEST),
            message: format!(
                "{} cells make a manifest of {:.1} MiB, more than the {} MiB a grid may have: \
                 use larger cells, or compile the area as regions (docs/fleet.md)",
                manifest.cells.len(),
                text.len() as f64 / (1 << 20) as f64,
                MAX_MANIFEST_BYTES >> 20
            ),
        });
    }
    crate::input::write_atomic(&dir.join(MANIFEST), text.as_bytes())?;
    remove_cells_not_in(&dir.join("cells"), &manifest)?;
    Ok(manifest)
}

/// Removes from `cells_dir` every cell file (a name [`cell_file_name`] gives) that `manifest`
/// does not list: the cells of an earlier grid written into the same folder, which no reader
/// opens but a copy of the folder would carry. Other files are left alone; no `cells_dir`, no
/// cells.
fn remove_cells_not_in(cells_dir: &Path, manifest: &Manifest) -> Result<(), GridError> {
    let listed: std::collections::HashSet<CellKey> =
        manifest.cells.iter().map(|c| [c.x, c.y]).collect();
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| InputError::Io { path, source }
    };
    let entries = match std::fs::read_dir(cells_dir) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        read => read.map_err(io(cells_dir))?,
    };
    for entry in entries {
        let entry = entry.map_err(io(cells_dir))?;
        let name = entry.file_name();
        let stale = name
            .to_str()
            .and_then(cell_key_of_file_name)
            .is_some_and(|key| !listed.contains(&key));
        if stale {
            std::fs::remove_file(entry.path()).map_err(io(&entry.path()))?;
        }
    }
    Ok(())
}

/// The cell whose file [`cell_file_name`] names `name`, if it names one.
fn cell_key_of_file_name(name: &str) -> Option<CellKey> {
    let (x, y) = name.strip_suffix(".tile")?.split_once('_')?;
    let key = [x.parse().ok()?, y.parse().ok()?];
    (cell_file_name(key) == name).then_some(key)
}

/// What a manifest records of the whole map: its lane and point counts and bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapSummary {
    /// Lanes with at least one point.
    pub lanes: u64,
    /// Lane points.
    pub points: u64,
    /// Bounding box of every point `[min x, min y, max x, max y]` (metres, map plane).
    pub bounds: [f64; 4],
}

impl MapSummary {
    /// The summary of a map without lanes, to [`add`](MapSummary::add) lanes to.
    pub fn empty() -> MapSummary {
        MapSummary {
            lanes: 0,
            points: 0,
            bounds: tile::bounds(&[]),
        }
    }

    /// The summary of `map`.
    pub fn of(map: &LaneMap) -> MapSummary {
        MapSummary {
            lanes: map.lane_count() as u64,
            points: map.len() as u64,
            bounds: tile::bounds(map.points()),
        }
    }

    /// Adds one lane's points (metres, map plane); a lane without points adds nothing.
    pub fn add(&mut self, points: &[[f64; 2]]) {
        if points.is_empty() {
            return;
        }
        let b = tile::bounds(points);
        self.lanes += 1;
        self.points += points.len() as u64;
        self.bounds = [
            self.bounds[0].min(b[0]),
            self.bounds[1].min(b[1]),
            self.bounds[2].max(b[2]),
            self.bounds[3].max(b[3]),
        ];
    }
}

/// The manifest of a map summed up by `summary` cut into cells `entries` as `spec` says.
fn manifest_of(summary: &MapSummary, spec: &GridSpec, cells: Vec<CellEntry>) -> Manifest {
    Manifest {
        format: MANIFEST_FORMAT,
        map_version: spec.map_version,
        cell_size_m: spec.cell_size_m,
        margin_m: spec.margin_m,
        projection: spec.plane.projection.name().into(),
        origin_lat: spec.plane.origin_lat,
        origin_lon: spec.plane.origin_lon,
        spacing_m: spec.spacing_m,
        traffic: match spec.geometry.traffic {
            Traffic::Right => "right".into(),
            Traffic::Left => "left".into(),
        },
        road_classes: spec.geometry.classes.bits(),
        unmarked_offset_scale: spec.geometry.unmarked_offset_scale,
        lanes: summary.lanes,
        points: summary.points,
        bounds: summary.bounds,
        cells,
    }
}

/// A grid in memory: its manifest and each cell's key and tile bytes.
pub type EncodedGrid = (Manifest, Vec<(CellKey, Vec<u8>)>);

/// A grid of `map` in memory, on the caller's thread: its manifest and each cell's tile bytes
/// (what [`write`](fn@write) writes, for tools and tests that do not need files).
pub fn encode(map: &LaneMap, spec: &GridSpec) -> Result<EncodedGrid, GridError> {
    tile::check_map_version(spec.map_version)?;
    let cells = partition(map, spec.cell_size_m, spec.margin_m)?;
    let mut entries = Vec::with_capacity(cells.len());
    let mut bytes = Vec::with_capacity(cells.len());
    for cell in &cells {
        let (entry, tile) = encode_one(cell, spec)?;
        entries.push(entry);
        bytes.push((cell.key, tile));
    }
    Ok((manifest_of(&MapSummary::of(map), spec, entries), bytes))
}

/// One cell's tile bytes and its manifest entry.
fn encode_one(cell: &CellContent, spec: &GridSpec) -> Result<(CellEntry, Vec<u8>), GridError> {
    let key = cell.key;
    let square = square_of(key, spec.cell_size_m);
    let mut bytes = tile::encode_cell(
        &cell.pieces,
        &cell.origins,
        square,
        spec.plane,
        spec.spacing_m,
        spec.geometry,
    );
    tile::set_map_version(&mut bytes, spec.map_version)?;
    if let Some(key) = spec.sign {
        tile::sign(&mut bytes, key);
    }
    let info = tile::read_info(Path::new(""), &bytes)?;
    let entry = CellEntry {
        x: key[0],
        y: key[1],
        checksum: format!("{:016x}", info.checksum),
        bytes: bytes.len() as u64,
        points: cell.pieces.len() as u64,
    };
    Ok((entry, bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_a_cells_own_file_name_names_a_cell() {
        for key in [[0, 0], [-1, 2], [i32::MIN, i32::MAX]] {
            assert_eq!(cell_key_of_file_name(&cell_file_name(key)), Some(key));
        }
        for name in [
            "0_0.tile.tmp",
            "+1_0.tile",
            "01_0.tile",
            "1_0",
            "a_b.tile",
            "1_2_3.tile",
        ] {
            assert_eq!(cell_key_of_file_name(name), None, "{name}");
        }
    }
}
