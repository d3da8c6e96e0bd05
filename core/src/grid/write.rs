//! Writing a map as a grid: every cell's tile and the manifest, to a folder or in memory.

use std::path::Path;

use crate::geo::MapPlane;
use crate::input::InputError;
use crate::lane_geometry::{LaneGeometry, Traffic};
use crate::lane_map::LaneMap;
use crate::tile::{self, SigningKey};

use super::{
    cell_file_name, partition, square_of, CellContent, CellEntry, CellKey, GridError, Manifest,
    MANIFEST, MANIFEST_FORMAT,
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
    /// Sign every cell with this key.
    pub sign: Option<&'a SigningKey>,
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
    let cells = partition(map, spec.cell_size_m, spec.margin_m)?;
    let cells_dir = dir.join("cells");
    std::fs::create_dir_all(&cells_dir).map_err(|source| InputError::Io {
        path: cells_dir.clone(),
        source,
    })?;
    let chunk = cells.len().div_ceil(encode_threads.max(1)).max(1);
    let entries: Vec<Result<Vec<CellEntry>, GridError>> = std::thread::scope(|scope| {
        let handles: Vec<_> = cells
            .chunks(chunk)
            .map(|part| {
                scope.spawn(|| {
                    part.iter()
                        .map(|c| write_cell(&cells_dir, c, spec))
                        .collect()
                })
            })
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
    let manifest = manifest_of(map, spec, cell_entries);
    let text = toml::to_string(&manifest).map_err(|e| GridError::Manifest {
        path: dir.join(MANIFEST),
        message: e.to_string(),
    })?;
    crate::input::write_atomic(&dir.join(MANIFEST), text.as_bytes())?;
    Ok(manifest)
}

/// The manifest of `map` cut into cells `entries` as `spec` says.
fn manifest_of(map: &LaneMap, spec: &GridSpec, cells: Vec<CellEntry>) -> Manifest {
    Manifest {
        format: MANIFEST_FORMAT,
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
        lanes: map.lane_count() as u64,
        points: map.len() as u64,
        bounds: tile::bounds(map.points()),
        cells,
    }
}

/// A grid in memory: its manifest and each cell's key and tile bytes.
pub type EncodedGrid = (Manifest, Vec<(CellKey, Vec<u8>)>);

/// A grid of `map` in memory, on the caller's thread: its manifest and each cell's tile bytes
/// (what [`write`](fn@write) writes, for tools and tests that do not need files).
pub fn encode(map: &LaneMap, spec: &GridSpec) -> Result<EncodedGrid, GridError> {
    let cells = partition(map, spec.cell_size_m, spec.margin_m)?;
    let mut entries = Vec::with_capacity(cells.len());
    let mut bytes = Vec::with_capacity(cells.len());
    for cell in &cells {
        let (entry, tile) = encode_one(cell, spec)?;
        entries.push(entry);
        bytes.push((cell.key, tile));
    }
    Ok((manifest_of(map, spec, entries), bytes))
}

fn write_cell(
    cells_dir: &Path,
    cell: &CellContent,
    spec: &GridSpec,
) -> Result<CellEntry, GridError> {
    let (entry, bytes) = encode_one(cell, spec)?;
    tile::write_bytes(&cells_dir.join(cell_file_name(cell.key)), &bytes)?;
    Ok(entry)
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
