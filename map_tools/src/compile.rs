//! Compiling road data into a lane map: read every input, choose the map plane, derive lanes.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, RecvTimeoutError};
use std::thread::JoinHandle;
use std::time::Duration;

use lanealign_core::geo::{check_lat_lon, GeoError, MapPlane, Projection};
use lanealign_core::grid::{self, GridError, GridSpec, Manifest};
use lanealign_core::lane_geometry::{LaneGeometry, RoadClasses};
use lanealign_core::lane_map::{Lane, LaneMap, LaneMapError};
use lanealign_core::tile::{SigningKey, TileError};

use crate::lane_spill::SpillError;
use crate::lanelet2::{derive_lanelet_lanes, is_lanelet2, LaneletReport};
use crate::node_store::NodeStoreError;
use crate::osm::{read_xml_file, MergedNodes, NodePositions, OsmData, OsmError};
use crate::osm_lanes::{
    derive_way_lanes, DeriveReport, EarlierRoads, LaneOptions, MAX_NODE_GAP_M, MAX_PLANE_RADIUS_M,
};
use crate::pbf::{read_pbf_file, PbfError};

/// What compiling needs besides the inputs.
#[derive(Clone, Debug, Default)]
pub struct CompileOptions {
    /// The map plane's origin `(lat, lon)` in degrees; the centre of the data when `None`.
    pub origin: Option<(f64, f64)>,
    /// The projection of the map plane.
    pub projection: Projection,
    /// Lane derivation from raw OSM (spacing, traffic side, classes); the spacing also applies
    /// to Lanelet2 centerlines.
    pub lanes: LaneOptions,
}

/// What one input contributed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum InputReport {
    /// Raw OSM (XML or PBF): lanes derived from ways.
    Osm(DeriveReport),
    /// A Lanelet2 map: lanes from lanelets.
    Lanelet2(LaneletReport),
}

impl std::fmt::Display for InputReport {
    /// What the input contributed, in a sentence (`compile` prints one per input).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            InputReport::Osm(r) => write!(
                f,
                "OSM, {} ways read: {} drivable -> {} lanes; skipped {} not drivable, {} without \
                 geometry (fewer than 2 known nodes, nodes over {} km apart, or over {} km from \
                 the map's origin){}; {} missing node references",
                r.ways_read(),
                r.ways_used,
                r.lanes,
                r.ways_not_drivable,
                r.ways_without_geometry,
                MAX_NODE_GAP_M / 1000.0,
                MAX_PLANE_RADIUS_M / 1000.0,
                match r.ways_in_earlier_input {
                    0 => String::new(),
                    n => format!(", {n} already read from an earlier input"),
                },
                r.missing_node_refs
            ),
            InputReport::Lanelet2(r) => write!(
                f,
                "Lanelet2, {} drivable lanelets; {} not drivable, {} with broken bounds{}",
                r.lanelets_used,
                r.lanelets_not_drivable,
                r.lanelets_broken,
                match r.lanes_in_earlier_input {
                    0 => String::new(),
                    n => format!("; {n} lanes already read from an earlier input"),
                }
            ),
        }
    }
}

/// The inputs' reports, one `path: report` after another.
fn each_input(reports: &[(PathBuf, InputReport)]) -> String {
    reports
        .iter()
        .map(|(path, report)| format!("{}: {report}", path.display()))
        .collect::<Vec<_>>()
        .join("; ")
}

/// A compile that failed.
#[derive(Debug, thiserror::Error)]
pub enum CompileError {
    /// No input gave a lane; what each contributed.
    #[error("no input gave a lane: {}", each_input(.0))]
    NoLanes(Vec<(PathBuf, InputReport)>),
    /// An XML input could not be read.
    #[error(transparent)]
    Osm(#[from] OsmError),
    /// A PBF input could not be read.
    #[error(transparent)]
    Pbf(#[from] PbfError),
    /// An input is neither `.osm` nor `.osm.pbf`.
    #[error("{0}: unknown input type (expected .osm or .osm.pbf)")]
    UnknownInput(PathBuf),
    /// No input had a node to place the map at.
    #[error("the inputs contain no nodes")]
    NoNodes,
    /// The map plane's origin given is no place on Earth.
    #[error("origin: {0}")]
    Origin(#[from] GeoError),
    /// The lanes do not make a map.
    #[error(transparent)]
    Map(#[from] LaneMapError),
    /// The grid could not be written.
    #[error(transparent)]
    Grid(#[from] GridError),
    /// The scratch file of node locations of a streaming compile failed.
    #[error("in {dir}: {source}")]
    NodeScratch {
        /// The folder it was in (the output's).
        dir: PathBuf,
        /// What failed.
        source: NodeStoreError,
    },
    /// A scratch file of derived lanes of a streaming compile failed.
    #[error("in {dir}: {source}")]
    LaneScratch {
        /// The folder it was in (the output's).
        dir: PathBuf,
        /// What failed.
        source: SpillError,
    },
    /// A way appears twice in one input, so its lanes have no place in the map's order.
    #[error("{path}: way {way} appears more than once (an OSM file holds each way once)")]
    DuplicateWay {
        /// The input.
        path: PathBuf,
        /// The way's id.
        way: i64,
    },
}

/// Whether `path` names a PBF input (`.osm.pbf`, `.pbf`; any case).
pub fn is_pbf(path: &Path) -> bool {
    path.to_string_lossy().to_lowercase().ends_with(".pbf")
}

/// Reads one input by its extension: `.osm.pbf` / `.pbf` as PBF, `.osm` / `.xml` as XML.
pub fn read_input(path: &Path) -> Result<OsmData, CompileError> {
    let name = path.to_string_lossy().to_lowercase();
    if is_pbf(path) {
        Ok(read_pbf_file(path)?)
    } else if name.ends_with(".osm") || name.ends_with(".xml") {
        Ok(read_xml_file(path)?)
    } else {
        Err(CompileError::UnknownInput(path.to_path_buf()))
    }
}

/// A spinner that shows itself on a terminal only when reading takes more than a second. Its
/// thread waits for [`Spinner::finish`] rather than sleeping, and `finish` joins it: a call of
/// [`compile`] leaves no thread behind (one that slept out its second outlived every quick
/// read, hundreds at a time in a loop of small compiles).
struct Spinner {
    bar: indicatif::ProgressBar,
    stop: mpsc::Sender<()>,
    thread: JoinHandle<()>,
}

impl Spinner {
    fn start(message: String) -> Spinner {
        let bar =
            indicatif::ProgressBar::with_draw_target(None, indicatif::ProgressDrawTarget::hidden());
        bar.set_message(message);
        let (stop, stopped) = mpsc::channel::<()>();
        let late_bar = bar.clone();
        let thread = std::thread::spawn(move || {
            if stopped.recv_timeout(Duration::from_secs(1)) == Err(RecvTimeoutError::Timeout) {
                late_bar.set_draw_target(indicatif::ProgressDrawTarget::stderr());
                late_bar.enable_steady_tick(Duration::from_millis(120));
            }
        });
        Spinner { bar, stop, thread }
    }

    /// Ends the spinner's thread and clears the spinner if it was shown.
    fn finish(self) {
        let Spinner { bar, stop, thread } = self;
        drop(stop);
        // The thread only waits and redraws; a panic in it has been reported by the hook.
        let _ = thread.join();
        bar.finish_and_clear();
    }
}

/// The bounds of node positions `[min lat, min lon, max lat, max lon]` (nanodegrees), whose
/// centre is the map plane's origin when none is given.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct NodeBounds([i64; 4]);

impl NodeBounds {
    /// The bounds of no node.
    pub(crate) const EMPTY: NodeBounds = NodeBounds([i64::MAX, i64::MAX, i64::MIN, i64::MIN]);

    /// Widened to hold a node at `lat`, `lon` (nanodegrees).
    pub(crate) fn add(&mut self, lat: i64, lon: i64) {
        self.join(NodeBounds([lat, lon, lat, lon]));
    }

    /// Widened to hold `other`.
    pub(crate) fn join(&mut self, other: NodeBounds) {
        let (b, o) = (&mut self.0, other.0);
        *b = [
            b[0].min(o[0]),
            b[1].min(o[1]),
            b[2].max(o[2]),
            b[3].max(o[3]),
        ];
    }

    /// The centre `(lat, lon)` in degrees; `None` for the bounds of no node.
    pub(crate) fn centre(self) -> Option<(f64, f64)> {
        let b = self.0;
        (b[0] <= b[2]).then(|| ((b[0] + b[2]) as f64 / 2e9, (b[1] + b[3]) as f64 / 2e9))
    }
}

fn centre(inputs: &[OsmData]) -> Option<(f64, f64)> {
    let mut bounds = NodeBounds::EMPTY;
    for &(lat, lon) in inputs.iter().flat_map(|d| d.nodes.values()) {
        bounds.add(lat, lon);
    }
    bounds.centre()
}

/// A compiled lane map and everything a tile records about it.
pub struct Compiled {
    /// The lanes.
    pub map: LaneMap,
    /// The plane they are in.
    pub plane: MapPlane,
    /// How they were derived.
    pub geometry: LaneGeometry,
    /// What each input contributed, in input order.
    pub reports: Vec<InputReport>,
}

impl Compiled {
    /// The tile bytes of this map (points resampled at `spacing_m`).
    pub fn tile_bytes(&self, spacing_m: f64) -> Vec<u8> {
        lanealign_core::tile::encode(&self.map, &self.plane, spacing_m, &self.geometry)
    }

    /// The tile bytes of this map as a build ships them: points resampled at `spacing_m`,
    /// carrying the builder's `map_version` (0: none), signed with `sign` when given.
    pub fn shipped_tile_bytes(
        &self,
        spacing_m: f64,
        map_version: u64,
        sign: Option<&SigningKey>,
    ) -> Result<Vec<u8>, TileError> {
        let mut bytes = self.tile_bytes(spacing_m);
        lanealign_core::tile::set_map_version(&mut bytes, map_version)?;
        if let Some(key) = sign {
            lanealign_core::tile::sign(&mut bytes, key);
        }
        Ok(bytes)
    }

    /// Writes this map as a grid into folder `output` (cells of `cell_size_m` holding the lanes
    /// within `margin_m` of their squares; the manifest and each cell carrying `map_version` and
    /// signed with `sign` when given), encoding cells on every core; returns its manifest.
    pub fn write_grid(
        &self,
        output: &Path,
        spacing_m: f64,
        cell_size_m: f64,
        margin_m: f64,
        sign: Option<&SigningKey>,
        map_version: u64,
    ) -> Result<Manifest, GridError> {
        let spec = GridSpec {
            plane: &self.plane,
            spacing_m,
            geometry: &self.geometry,
            cell_size_m,
            margin_m,
            sign,
            map_version,
        };
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        grid::write(output, &self.map, &spec, threads)
    }
}

/// Appends to `lanes` the lanes of the ways of OSM input `osm` (read from `path`) that no input
/// before holds as a road, its nodes placed by `nodes`; what derivation did. A way given twice in
/// the input is refused.
fn add_osm_lanes(
    path: &Path,
    osm: &OsmData,
    nodes: &impl NodePositions,
    earlier_roads: &EarlierRoads,
    plane: &MapPlane,
    options: &CompileOptions,
    lanes: &mut Vec<Lane>,
) -> Result<DeriveReport, CompileError> {
    let mut report = DeriveReport::default();
    let mut last_with_lanes = None;
    for way in &osm.ways {
        if earlier_roads.took(way, &mut report) {
            continue;
        }
        let before = lanes.len();
        derive_way_lanes(way, nodes, plane, &options.lanes, &mut report, lanes);
        // Ways come by id: a way given twice gives its lanes twice in a row.
        if lanes.len() > before {
            if last_with_lanes == Some(way.id) {
                return Err(CompileError::DuplicateWay {
                    path: path.to_path_buf(),
                    way: way.id,
                });
            }
            last_with_lanes = Some(way.id);
        }
    }
    Ok(report)
}

/// Appends to `lanes` the lanes of `derived` (one Lanelet2 input's) but those an input before
/// gave: the same id with the same points (tiles of one map share their borders' lanelets; a
/// Lanelet2 map's ids are its own, so the same id elsewhere is another lanelet). `taken` holds
/// where in `lanes` every Lanelet2 lane taken lies, by id. Returns how many were given before.
fn add_untaken_lanes(
    derived: Vec<Lane>,
    taken: &mut HashMap<u64, Vec<usize>>,
    lanes: &mut Vec<Lane>,
) -> usize {
    let mut again = 0;
    let first_of_input = lanes.len();
    for lane in derived {
        let earlier = taken.get(&lane.id).map_or(&[][..], Vec::as_slice);
        if earlier.iter().any(|&k| lanes[k].points == lane.points) {
            again += 1;
        } else {
            lanes.push(lane);
        }
    }
    // Taken after the input, so that its own lanes under one id are all kept.
    for (k, lane) in lanes.iter().enumerate().skip(first_of_input) {
        taken.entry(lane.id).or_default().push(k);
    }
    again
}

/// The map plane's origin `(lat, lon)` (degrees): `given`, checked (a NaN origin compiled a map
/// with no lane), else the data's `centre` (found only then: it walks every node).
pub(crate) fn plane_origin(
    given: Option<(f64, f64)>,
    centre: impl FnOnce() -> Option<(f64, f64)>,
) -> Result<(f64, f64), CompileError> {
    match given {
        Some((lat, lon)) => {
            check_lat_lon(lat, lon)?;
            Ok((lat, lon))
        }
        None => centre().ok_or(CompileError::NoNodes),
    }
}

/// Reads every input and derives its lanes into one map, in input order.
pub fn compile(inputs: &[PathBuf], options: &CompileOptions) -> Result<Compiled, CompileError> {
    let mut data = Vec::with_capacity(inputs.len());
    for path in inputs {
        let spinner = Spinner::start(format!("reading {}", path.display()));
        let read = read_input(path);
        spinner.finish();
        data.push(read?);
    }
    let (lat, lon) = plane_origin(options.origin, || centre(&data))?;
    let plane = MapPlane::new(options.projection, lat, lon);
    let mut lanes: Vec<Lane> = Vec::new();
    let mut reports = Vec::with_capacity(data.len());
    let lanelet2: Vec<bool> = data.iter().map(is_lanelet2).collect();
    let osm_inputs: Vec<&OsmData> = data
        .iter()
        .zip(&lanelet2)
        .filter_map(|(osm, &lanelet2)| (!lanelet2).then_some(osm))
        .collect();
    let mut earlier_roads = EarlierRoads::default();
    let mut lanelet_lanes_taken = HashMap::new();
    for ((osm, &lanelet2), path) in data.iter().zip(&lanelet2).zip(inputs) {
        reports.push(if lanelet2 {
            let spacing_m = options.lanes.spacing_m;
            let (derived, mut report) = derive_lanelet_lanes(osm, &plane, spacing_m);
            report.lanes_in_earlier_input =
                add_untaken_lanes(derived, &mut lanelet_lanes_taken, &mut lanes);
            InputReport::Lanelet2(report)
        } else {
            let nodes = MergedNodes::new(osm, &osm_inputs);
            let report = add_osm_lanes(
                path,
                osm,
                &nodes,
                &earlier_roads,
                &plane,
                options,
                &mut lanes,
            )?;
            earlier_roads.add(
                osm.ways
                    .iter()
                    .filter_map(|w| EarlierRoads::id_of(w, &options.lanes)),
            );
            InputReport::Osm(report)
        });
    }
    let from_osm_ways = !osm_inputs.is_empty();
    let geometry = if from_osm_ways {
        options.lanes.geometry()
    } else {
        LaneGeometry {
            traffic: options.lanes.traffic,
            classes: RoadClasses::EMPTY,
            unmarked_offset_scale: None,
        }
    };
    if lanes.iter().all(|l| l.points.is_empty()) {
        return Err(CompileError::NoLanes(
            inputs.iter().cloned().zip(reports).collect(),
        ));
    }
    Ok(Compiled {
        map: LaneMap::new(&lanes)?,
        plane,
        geometry,
        reports,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An origin given is checked as an anchor's is (a NaN one compiled a map with no lane, and
    /// `compile` said only that the map was empty); without one, the data's centre is the origin.
    #[test]
    fn an_origin_given_must_be_a_place_on_earth() {
        let refused = |origin| plane_origin(Some(origin), || None).map_err(|e| e.to_string());
        assert_eq!(
            refused((f64::NAN, 8.0)),
            Err("origin: latitude NaN is outside [-90, 90] degrees".to_string())
        );
        assert_eq!(
            refused((49.0, 1e300)),
            Err("origin: longitude 1e300 is outside [-180, 180] degrees".to_string())
        );
        assert_eq!(refused((49.0, 8.4)), Ok((49.0, 8.4)));
        assert_eq!(
            plane_origin(None, || Some((1.0, 2.0))).ok(),
            Some((1.0, 2.0))
        );
        assert!(matches!(
            plane_origin(None, || None),
            Err(CompileError::NoNodes)
        ));
    }
}
