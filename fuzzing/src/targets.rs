//! One harness per kind of untrusted input: each runs the product's reading path, and what a
//! reader hands on to the rest (a lane map, poses, sessions) is used, so that a reader that
//! accepts something it should not is caught where it would hurt. Returning an error is a
//! correct answer; a panic is a bug.

use std::collections::{BTreeMap, HashSet};
use std::path::Path;
use std::sync::{Arc, OnceLock};

use lanealign_cli::maps::LoadedMap;
use lanealign_core::corrector::{MatchMode, Status};
use lanealign_core::grid::{self, CellKey, EncodedGrid, Grid, GridCell, GridSpec, LoadPolicy};
use lanealign_core::lane_map::LaneMap;
use lanealign_core::params::{Method, Params, Preset};
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::se2::Se2;
use lanealign_core::source_corrector::{CorrectedPose, Placement, SourceCorrector};
use lanealign_core::trajectory::{self, Format};
use lanealign_core::{lane_csv, plausibility, tile};
use lanealign_map::compile::{compile, CompileError, CompileOptions};
use lanealign_map::grid_compile::{compile_grid, GridOptions};
use lanealign_map::lanelet2::derive_lanelet_lanes;
use lanealign_map::osm::read_xml;
use lanealign_map::osm_lanes::{derive_lanes, LaneOptions};
use lanealign_map::pbf::read_pbf;
use lanealign_service::config::Config;
use lanealign_service::journal::{self, Header};
use lanealign_service::session::{self, Session, SessionSetup};
use lanealign_wire::payload::{self, OdomPose, StatusCode, FLAG_END_SESSION};

use crate::seeds::{self, ODOM_POSE_BYTES};

/// A kind of untrusted input. The five that read a lane map (a tile, OSM XML, PBF, Lanelet2,
/// lane CSV) query it and correct a drive along it in both match modes ([`drive_twins`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Target {
    /// A lane tile.
    Tile,
    /// One cell of a tile grid (listed in the manifest with its own checksum), joined with the
    /// grid's other cells, corrected on and swapped away from, in both match modes.
    GridCell,
    /// Raw OSM XML.
    OsmXml,
    /// OSM PBF.
    Pbf,
    /// A tile grid's manifest, opened as the daemon opens it at start and on SIGHUP: its
    /// summary taken, the cells wanted around a drive and far away listed, the seed grid's cells
    /// it accepts joined and corrected on in both match modes.
    GridManifest,
    /// OSM PBF compiled into a grid as it streams, against the grid of the map read in memory.
    PbfGrid,
    /// A Lanelet2 map (OSM XML with lanelet relations).
    Lanelet2,
    /// A KITTI pose file.
    Kitti,
    /// A TUM pose file.
    Tum,
    /// Lane CSV.
    LaneCsv,
    /// The daemon's TOML configuration.
    DaemonToml,
    /// A stream of wire payloads ([`OdomPose`]) into one source's sessions.
    Wire,
    /// A session's snapshot in the daemon's journal (its checksum recomputed), restored as a
    /// restarted daemon restores it and then answering poses.
    Snapshot,
    /// A stream of wire payloads into one journaled session, then the session restored from its
    /// journal as a restarted daemon restores it: the two go on alike (differential).
    Journal,
    /// Poses and stamps as bare numbers, the way the Python package's `correct` takes them from
    /// arrays (no reader refuses NaN, infinities, 1e300, degenerate rotations or stamps out of
    /// order first), corrected and warned about as `lanealign correct` does.
    PoseArray,
}

type Outcome = Result<(), String>;

impl Target {
    /// Every target.
    pub const ALL: [Target; 15] = [
        Target::Tile,
        Target::GridCell,
        Target::GridManifest,
        Target::OsmXml,
        Target::Pbf,
        Target::PbfGrid,
        Target::Lanelet2,
        Target::Kitti,
        Target::Tum,
        Target::LaneCsv,
        Target::DaemonToml,
        Target::Wire,
        Target::Snapshot,
        Target::Journal,
        Target::PoseArray,
    ];

    /// The target's name (as in `fuzz/fuzz_targets/`).
    pub fn name(self) -> &'static str {
        match self {
            Target::Tile => "tile",
            Target::GridCell => "grid_cell",
            Target::GridManifest => "grid_manifest",
            Target::OsmXml => "osm_xml",
            Target::Pbf => "pbf",
            Target::PbfGrid => "pbf_grid",
            Target::Lanelet2 => "lanelet2",
            Target::Kitti => "kitti",
            Target::Tum => "tum",
            Target::LaneCsv => "lane_csv",
            Target::DaemonToml => "daemon_toml",
            Target::Wire => "wire",
            Target::Snapshot => "snapshot",
            Target::Journal => "journal",
            Target::PoseArray => "pose_array",
        }
    }

    /// Runs the harness on `bytes`: `Err` when the input is refused (a correct answer).
    pub fn run(self, bytes: &[u8]) -> Outcome {
        let err = |e: &dyn std::fmt::Display| e.to_string();
        match self {
            Target::Tile | Target::OsmXml | Target::Lanelet2 | Target::Pbf | Target::LaneCsv => {
                let map = self.read_map(bytes)?;
                query(&map);
                drive_twins(&Arc::new(map));
                Ok(())
            }
            Target::GridCell => grid_cell(bytes),
            Target::GridManifest => grid_manifest(bytes),
            Target::PbfGrid => pbf_grid(bytes),
            Target::Kitti | Target::Tum => {
                let format = if self == Target::Kitti {
                    Format::Kitti
                } else {
                    Format::Tum
                };
                let traj =
                    trajectory::parse(bytes, Path::new("fuzz.txt"), format).map_err(|e| err(&e))?;
                correct(&traj.poses, traj.stamps.as_deref())
            }
            Target::DaemonToml => {
                let text = std::str::from_utf8(bytes).map_err(|e| err(&e))?;
                let path = Path::new("/etc/lanealign/fuzz.toml");
                let config = Config::parse(text, path).map_err(|e| err(&e))?;
                config.resolve(path).map_err(|e| err(&e))?;
                Ok(())
            }
            Target::Wire => {
                serve(bytes, &wire_setup());
                Ok(())
            }
            Target::Snapshot => restored(bytes),
            Target::Journal => journaled(bytes),
            Target::PoseArray => pose_array(bytes),
        }
    }

    /// The lane map a reader of maps makes of `bytes` (a tile; OSM XML, PBF or Lanelet2 with
    /// every lane derived; lane CSV), as the product loads it. `Err` when the reader refuses
    /// the bytes or the target reads no map.
    pub fn read_map(self, bytes: &[u8]) -> Result<LaneMap, String> {
        let err = |e: &dyn std::fmt::Display| e.to_string();
        let (plane, _) = seeds::tile_plane_and_geometry();
        let lanes = match self {
            Target::Tile => {
                let (map, _) = tile::decode(Path::new("fuzz.tile"), bytes).map_err(|e| err(&e))?;
                return Ok(map);
            }
            Target::OsmXml => {
                let osm = read_xml(bytes, Path::new("fuzz.osm")).map_err(|e| err(&e))?;
                derive_lanes(&osm, &plane, &LaneOptions::default()).0
            }
            Target::Lanelet2 => {
                let osm = read_xml(bytes, Path::new("fuzz.osm")).map_err(|e| err(&e))?;
                derive_lanelet_lanes(&osm, &plane, 3.0).0
            }
            Target::Pbf => {
                let osm = read_pbf(bytes, Path::new("fuzz.osm.pbf")).map_err(|e| err(&e))?;
                derive_lanes(&osm, &plane, &LaneOptions::default()).0
            }
            Target::LaneCsv => {
                lane_csv::parse(bytes, Path::new("fuzz.csv")).map_err(|e| err(&e))?
            }
            _ => return Err(format!("{} reads no lane map", self.name())),
        };
        LaneMap::new(&lanes).map_err(|e| err(&e))
    }

    /// The seeds the mutator starts from.
    pub fn seeds(self) -> Vec<Vec<u8>> {
        match self {
            Target::Tile => seeds::tiles(),
            Target::GridCell => seed_grid().1.iter().map(|(_, b)| b.clone()).collect(),
            Target::OsmXml => vec![seeds::OSM_XML.as_bytes().to_vec()],
            Target::Pbf | Target::PbfGrid => vec![crate::pbf_writer::write(
                &read_xml(seeds::OSM_XML.as_bytes(), Path::new("seed.osm")).expect("seed reads"),
            )],
            Target::Lanelet2 => vec![seeds::LANELET2_XML.as_bytes().to_vec()],
            Target::Kitti => vec![seeds::trajectory_text(Format::Kitti)],
            Target::Tum => vec![seeds::trajectory_text(Format::Tum)],
            Target::LaneCsv => vec![seeds::lane_csv()],
            Target::GridManifest => {
                let text = toml::to_string(&seed_grid().0).expect("the seed manifest is written");
                let key = tile::SigningKey::from_bytes(&[9; 32]);
                let signed = grid::signature::sign(&text, &key);
                vec![text.into_bytes(), signed.into_bytes()]
            }
            Target::DaemonToml => vec![seeds::DAEMON_TOML.as_bytes().to_vec()],
            Target::Wire => vec![seeds::wire_stream()],
            Target::Journal => vec![seeds::wire_stream(), seeds::long_stream()],
            Target::Snapshot => seeds::snapshots(&snapshot_setup()),
            Target::PoseArray => seeds::pose_arrays(),
        }
    }

    /// Tokens the mutator inserts: what the format's reader branches on.
    pub fn dictionary(self) -> &'static [&'static [u8]] {
        const NUMBERS: [&[u8]; 9] = [
            b"nan",
            b"inf",
            b"-inf",
            b"1e308",
            b"-0",
            b"1e7",
            b"10000001",
            b"0x10",
            b"\r\n",
        ];
        match self {
            Target::OsmXml | Target::Lanelet2 => &[
                b"</osm>",
                b"<osm>",
                b"<way id=\"7\">",
                b"</way>",
                b"<nd ref=\"1\"/>",
                b"<node id=\"9\" lat=\"91\" lon=\"181\"/>",
                b"<tag k=\"lanes\" v=\"-3\"/>",
                b"<tag k=\"oneway\" v=\"-1\"/>",
                b"<tag k=\"width\" v=\"1e308\"/>",
                b"<relation id=\"1\">",
                b"</relation>",
                b"<member type=\"way\" ref=\"10\" role=\"left\"/>",
                b"&amp;",
                b"&#0;",
                b"<![CDATA[",
                b"<!--",
                b"-->",
                b"\"nan\"",
            ],
            Target::DaemonToml => &[
                b"[[source]]\n",
                b"anchor = { lat = 91, lon = 0, yaw_deg = 0 }\n",
                b"= 1e300\n",
                b"max_window = 0",
                b"\"\"",
                b"nan",
                b"-inf",
                b"[",
                b"{",
                b"}",
            ],
            Target::GridManifest => &[
                b"[[cells]]\n",
                b"x = 2147483647\n",
                b"y = -2147483648\n",
                b"bytes = 18446744073709551615\n",
                b"checksum = \"0000000000000000\"\n",
                b"points = 18446744073709551615\n",
                b"cell_size_m = 1e5\n",
                b"margin_m = 4e5\n",
                b"unmarked_offset_scale = nan\n",
                b"bounds = [nan, inf, -inf, 1e308]\n",
                b"projection = \"kitti\"\n",
                b"traffic = \"left\"\n",
                b"signer = \"",
                b"signature = \"",
                b"nan",
                b"1e308",
                b"-0",
            ],
            Target::Kitti | Target::Tum | Target::LaneCsv => &NUMBERS,
            Target::Tile
            | Target::GridCell
            | Target::Pbf
            | Target::PbfGrid
            | Target::Wire
            | Target::Snapshot
            | Target::Journal => &[],
            // Little-endian f64: NaN, inf, -inf, 1e300, -0, the smallest subnormal, 1e7 + 1.
            Target::PoseArray => &[
                &[0, 0, 0, 0, 0, 0, 248, 127],
                &[0, 0, 0, 0, 0, 0, 240, 127],
                &[0, 0, 0, 0, 0, 0, 240, 255],
                &[156, 117, 0, 136, 60, 228, 55, 126],
                &[0, 0, 0, 0, 0, 0, 0, 128],
                &[1, 0, 0, 0, 0, 0, 0, 0],
                &[0, 0, 0, 32, 208, 18, 99, 65],
            ],
        }
    }

    /// Makes a mutant reach past the integrity check most of the time: a tile's or a
    /// snapshot's mutant gets its checksum recomputed in 7 of 8 cases (else nearly every mutant
    /// stops at the checksum).
    pub fn prepare(self, mutant: &mut [u8], coin: u64) {
        if coin.is_multiple_of(8) {
            return;
        }
        match self {
            Target::Tile | Target::GridCell => tile::seal(mutant),
            Target::Snapshot => journal::seal(mutant),
            _ => {}
        }
    }
}

/// Compiles PBF `bytes` into a grid of 20 m cells as `lanealign-map compile --grid` does
/// (streaming) and cuts the map read in memory into the same grid: both refuse it, or the two
/// folders hold the same files with the same bytes (else a panic, the harness's finding). The
/// streaming compile may refuse a way twice in one input, which memory takes.
fn pbf_grid(bytes: &[u8]) -> Outcome {
    let err = |e: &dyn std::fmt::Display| e.to_string();
    let dir = tempfile::tempdir().map_err(|e| err(&e))?;
    let input = dir.path().join("fuzz.osm.pbf");
    std::fs::write(&input, bytes).map_err(|e| err(&e))?;
    let inputs = [input];
    let options = CompileOptions::default();
    let (cell_size_m, margin_m) = (20.0, 4.0);
    let grid = GridOptions {
        cell_size_m,
        margin_m,
        sign: None,
        map_version: 3,
    };
    let (streamed, in_memory) = (dir.path().join("streamed"), dir.path().join("in_memory"));
    let by_stream = compile_grid(&inputs, &options, &streamed, &grid);
    let by_memory = compile(&inputs, &options).and_then(|c| {
        c.write_grid(
            &in_memory,
            3.0,
            cell_size_m,
            margin_m,
            None,
            grid.map_version,
        )
        .map_err(CompileError::from)
    });
    match (by_stream, by_memory) {
        (Ok(_), Ok(_)) => {
            assert!(
                same_files(&streamed, &in_memory),
                "the streamed grid differs from the in-memory grid"
            );
            Ok(())
        }
        (Err(e), Err(_)) => Err(err(&e)),
        (Ok(_), Err(e)) => panic!("read in memory it is refused ({e}), streamed it is accepted"),
        (Err(e), Ok(_)) => panic!("read in memory it is accepted, streamed it is refused ({e})"),
    }
}

/// Whether grid folders `a` and `b` hold the same files with the same bytes.
fn same_files(a: &Path, b: &Path) -> bool {
    let listing = |dir: &Path| -> Vec<(std::ffi::OsString, Vec<u8>)> {
        let mut files: Vec<_> = ["manifest.toml"]
            .iter()
            .map(|name| {
                (
                    name.into(),
                    std::fs::read(dir.join(name)).unwrap_or_default(),
                )
            })
            .collect();
        if let Ok(cells) = std::fs::read_dir(dir.join("cells")) {
            for entry in cells.flatten() {
                files.push((
                    entry.file_name(),
                    std::fs::read(entry.path()).unwrap_or_default(),
                ));
            }
        }
        files.sort();
        files
    };
    listing(a) == listing(b)
}

/// Corrects a drive along `map`'s first lane ([`drive_along`]) in both match modes, which must
/// agree ([`same_answer`]), and returns how many of its poses were aligned (accepted).
pub fn drive_twins(map: &Arc<LaneMap>) -> usize {
    let mut fast = twin(map, MatchMode::Fast);
    let mut reference = twin(map, MatchMode::Reference);
    let mut accepted = 0;
    for (i, pose) in drive_along(map, DRIVE_ALONG_POSES).iter().enumerate() {
        let (answer, _) = fast.correct(pose);
        same_answer(i, &answer, &reference.correct(pose).0);
        accepted += usize::from(matches!(answer.status, Status::Accepted { .. }));
    }
    accepted
}

/// Asks `map` for the nearest points and the distance to its lanes, as the corrector and the
/// plausibility checks do, near and far.
fn query(map: &LaneMap) {
    let mut out = Vec::new();
    for p in [[0.0, 0.0], [20.0, 3.0], [-1e6, 1e6], [f64::MAX, 0.0]] {
        map.nearest(p, 8, &mut out);
        assert!(out.windows(2).all(|w| w[0].0 <= w[1].0), "nearest sorted");
        for &(_, j) in &out {
            let _ = map.segment_of(j);
        }
        let _ = plausibility::distance_to_lanes(map, p);
    }
}

/// The poses of the drive [`drive_twins`] corrects on a map: with a window of
/// [`HARNESS_MIN_WINDOW`], eleven alignments (from the 20th pose on).
const DRIVE_ALONG_POSES: usize = HARNESS_MIN_WINDOW + 10;

/// A corrector of the default method on `map` (the harnesses' window), matching in `mode`.
fn twin(map: &Arc<LaneMap>, mode: MatchMode) -> SourceCorrector {
    SourceCorrector::new(
        map.clone(),
        harness_params(Preset::KissIcp, Method::Robust),
        mode,
        placement(),
    )
}

/// The seed drive ([`seeds::drive`], `n` poses) moved to start on `map`'s first point, heading
/// along its first segment: on any map a reader accepts, the corrector then has lanes to match.
fn drive_along(map: &LaneMap, n: usize) -> Vec<Pose3> {
    let points = map.points();
    let start = points[0];
    let heading = match map.lane_offsets() {
        [0, end, ..] if *end >= 2 => (points[1][1] - start[1]).atan2(points[1][0] - start[0]),
        _ => 0.0,
    };
    let onto_map = Se2::new(heading, start[0], start[1]);
    seeds::drive(n)
        .iter()
        .map(|pose| {
            let [x, y] = onto_map.apply([pose.translation.x, pose.translation.y]);
            Pose3::planar(x, y, heading + pose.planar_heading(), pose.translation.z)
        })
        .collect()
}

/// The fast matcher changes the work, never the answer (docs/performance.md, where the two
/// agree bit for bit on the real runs): the two match modes' answers to pose `i` have the same
/// status and the same pose, correction and covariance, bit for bit (NaN where both are NaN:
/// the answer to a pose that is none).
fn same_answer(i: usize, fast: &CorrectedPose, reference: &CorrectedPose) {
    assert_eq!(
        fast.status, reference.status,
        "pose {i}: the match modes' statuses differ"
    );
    let same = |a: &f64, b: &f64| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan());
    let (f, r) = (fast.map_from_odom, reference.map_from_odom);
    let pose = |c: &CorrectedPose| c.pose.to_row_major();
    let correction = |s: Se2| [s.translation()[0], s.translation()[1], s.yaw()];
    assert!(
        pose(fast)
            .iter()
            .zip(&pose(reference))
            .all(|(a, b)| same(a, b))
            && correction(f)
                .iter()
                .zip(&correction(r))
                .all(|(a, b)| same(a, b)),
        "pose {i}: the match modes' corrections differ: {f:?} against {r:?}"
    );
    let covariances = |c: &CorrectedPose| c.covariance.concat();
    assert!(
        covariances(fast)
            .iter()
            .zip(&covariances(reference))
            .all(|(a, b)| same(a, b)),
        "pose {i}: the match modes' covariances differ: {:?} against {:?}",
        fast.covariance,
        reference.covariance
    );
}

/// The seed lanes as a grid of 20 m cells (margin 4 m): its manifest and cells.
fn seed_grid() -> &'static EncodedGrid {
    static GRID: OnceLock<EncodedGrid> = OnceLock::new();
    GRID.get_or_init(|| {
        let (plane, geometry) = seeds::tile_plane_and_geometry();
        let spec = GridSpec {
            plane: &plane,
            spacing_m: 3.0,
            geometry: &geometry,
            cell_size_m: 20.0,
            margin_m: 4.0,
            sign: None,
            map_version: 0,
        };
        grid::encode(&seeds::lane_map(), &spec).expect("the seed lanes make a grid")
    })
}

/// Loads `bytes` as the cell its square names, listed in the manifest with the bytes' own
/// checksum, length and point count, in bounds that hold its points (so that the cell's content,
/// not the manifest check, is what is tested), joins it with the other seed cells, corrects a
/// drive on the result and swaps to the grid without it.
fn grid_cell(bytes: &[u8]) -> Outcome {
    let err = |e: &dyn std::fmt::Display| e.to_string();
    let (manifest, cells) = seed_grid();
    let info = tile::read_info(Path::new("fuzz.tile"), bytes).map_err(|e| err(&e))?;
    let square = info.cell.ok_or("not a grid cell")?;
    let size = manifest.cell_size_m;
    let key = [
        (square[0] / size).floor() as i32,
        (square[1] / size).floor() as i32,
    ];
    let mut listed = manifest.clone();
    let entry = listed
        .cells
        .iter_mut()
        .find(|c| [c.x, c.y] == key)
        .ok_or("a square the grid has no cell for")?;
    entry.checksum = format!("{:016x}", info.checksum);
    entry.bytes = bytes.len() as u64;
    entry.points = info.points;
    // The whole map's totals and bounds as the listed cells can hold them (a cell with fewer
    // points, or points farther out).
    let held = listed
        .cells
        .iter()
        .fold(0u64, |sum, c| sum.saturating_add(c.points));
    listed.points = listed.points.min(held);
    listed.lanes = listed.lanes.min(listed.points);
    let corners = |b: [f64; 4]| [[b[0], b[1]], [b[2], b[3]]];
    listed.bounds = tile::bounds(&[corners(listed.bounds), corners(info.bounds)].concat());
    let text = toml::to_string(&listed).map_err(|e| err(&e))?;
    let grid = Grid::from_manifest(Path::new("fuzz-grid"), text.as_bytes()).map_err(|e| err(&e))?;
    let mutant = Arc::new(grid.cell_from_bytes(key, bytes).map_err(|e| err(&e))?);
    let others: Vec<Arc<GridCell>> = cells
        .iter()
        .filter(|(k, _)| *k != key)
        .map(|(k, b)| Arc::new(grid.cell_from_bytes(*k, b).expect("a seed cell loads")))
        .collect();
    let with: Vec<Arc<GridCell>> = others.iter().cloned().chain([mutant]).collect();
    let with = Arc::new(grid::assemble(&grid, &with).map_err(|e| err(&e))?);
    query(&with);
    let mut fast = twin(&with, MatchMode::Fast);
    let mut reference = twin(&with, MatchMode::Reference);
    let poses = seeds::drive(60);
    for (i, pose) in poses[..30].iter().enumerate() {
        same_answer(i, &fast.correct(pose).0, &reference.correct(pose).0);
    }
    if !others.is_empty() {
        let without = Arc::new(grid::assemble(&grid, &others).map_err(|e| err(&e))?);
        for j in 0..with.len() as u32 {
            if let Some(k) = grid::renumber(&with, &without, j) {
                assert_eq!(
                    with.points()[j as usize],
                    without.points()[k as usize],
                    "a renumbered point is the same point"
                );
            }
        }
        fast.replace_map(without.clone());
        reference.replace_map(without);
    }
    for (i, pose) in poses.iter().enumerate().skip(30) {
        let (answer, _) = fast.correct(pose);
        assert!(
            answer.pose.is_finite(),
            "a non-finite corrected pose on a grid"
        );
        same_answer(i, &answer, &reference.correct(pose).0);
    }
    Ok(())
}

/// Opens `bytes` as a grid's manifest ([`Grid::from_manifest`]), takes its summary as the
/// daemon does at start ([`Grid::info`]), lists the cells wanted around the seed drive and far
/// from it (each must be a cell the manifest lists), and joins the seed grid's cells the
/// manifest accepts (those it lists unchanged) into a map that is queried and corrected on.
fn grid_manifest(bytes: &[u8]) -> Outcome {
    let err = |e: &dyn std::fmt::Display| e.to_string();
    let grid = Grid::from_manifest(Path::new("fuzz-grid"), bytes).map_err(|e| err(&e))?;
    let _ = grid.info();
    let listed: HashSet<CellKey> = grid.cells().collect();
    let drive: Vec<[f64; 2]> = seeds::drive(40)
        .iter()
        .map(|p| [p.translation.x, p.translation.y])
        .collect();
    for window in [&drive[..], &[[1e7, -1e7], [-1e7, 1e7]], &[[f64::NAN, 0.0]]] {
        let wanted = grid.wanted(window, &LoadPolicy::default());
        assert!(
            wanted.iter().all(|key| listed.contains(key)),
            "a cell wanted that the manifest does not list"
        );
    }
    let (_, cells) = seed_grid();
    let accepted: Vec<Arc<GridCell>> = cells
        .iter()
        .filter_map(|(key, b)| grid.cell_from_bytes(*key, b).ok().map(Arc::new))
        .collect();
    if accepted.is_empty() {
        return Err("no seed cell is this grid's".into());
    }
    let map = grid::assemble(&grid, &accepted).map_err(|e| err(&e))?;
    query(&map);
    drive_twins(&Arc::new(map));
    Ok(())
}

fn seed_map() -> Arc<LaneMap> {
    static MAP: OnceLock<Arc<LaneMap>> = OnceLock::new();
    MAP.get_or_init(|| Arc::new(seeds::lane_map())).clone()
}

/// The parameters the harnesses correct with: `method`'s for `preset` (the robust method is the
/// product's default), with a window of [`HARNESS_MIN_WINDOW`] poses instead of the presets'
/// 150, so that the seed drives, whose lanes end after 42 m, are aligned: with 150 the
/// corrector would only ever warm up and refuse on them, and the matching, the ICP, the
/// covariance and the corrections applied would never see a mutant.
pub fn harness_params(preset: Preset, method: Method) -> Params {
    Params {
        min_window: HARNESS_MIN_WINDOW,
        ..method.params(preset)
    }
}

/// The harnesses' window before the first alignment (poses); a daemon's configuration may set
/// the same (`min_window`).
pub const HARNESS_MIN_WINDOW: usize = 20;

fn placement() -> Placement {
    Placement {
        convention: AxisConvention::Flu,
        anchored_from_odom: Se2::IDENTITY,
        smoothing: None,
    }
}

/// [`Target::PoseArray`]: a byte of options, then per pose 13 little-endian `f64`: its stamp
/// (seconds) and its 3x4 pose (row-major). Options: bit 0, the stamps are given; bit 1, the
/// paper's method; bit 2, the orb-slam3 preset (scale and stalls); bit 3, KITTI camera axes.
/// Every pose gets an answer, finite unless the pose is no pose, and the warnings are made.
fn pose_array(bytes: &[u8]) -> Outcome {
    let (&options, numbers) = bytes.split_first().ok_or("no options byte")?;
    let values: Vec<f64> = numbers
        .chunks_exact(8)
        .map(|b| f64::from_le_bytes(std::array::from_fn(|k| b[k])))
        .collect();
    let rows: Vec<&[f64]> = values.chunks_exact(13).collect();
    let stamps: Vec<f64> = rows.iter().map(|row| row[0]).collect();
    let poses: Vec<Pose3> = rows
        .iter()
        .map(|row| Pose3::from_row_major(&std::array::from_fn(|k| row[1 + k])))
        .collect();
    let params = harness_params(
        if options & 4 != 0 {
            Preset::OrbSlam3
        } else {
            Preset::KissIcp
        },
        if options & 2 != 0 {
            Method::Paper
        } else {
            Method::Robust
        },
    );
    let convention = if options & 8 != 0 {
        AxisConvention::KittiCamera
    } else {
        AxisConvention::Flu
    };
    let stamps = (options & 1 != 0).then_some(stamps.as_slice());
    let run = correct_as_the_command_does(&poses, stamps, params, convention)?;
    assert_eq!(run.len(), poses.len(), "a pose without an answer");
    for (corrected, pose) in run.iter().zip(&poses) {
        assert!(
            pose.problem().is_some() || corrected.pose.is_finite(),
            "a pose that is one was answered with a pose that is not finite"
        );
    }
    Ok(())
}

/// Corrects `poses` (stamped `stamps_s`, seconds, when given) on the seed lanes under `params`
/// and makes its warnings, as `lanealign correct` and the Python package's `correct` do
/// ([`LoadedMap`]).
fn correct_as_the_command_does(
    poses: &[Pose3],
    stamps_s: Option<&[f64]>,
    params: Params,
    convention: AxisConvention,
) -> Result<Vec<CorrectedPose>, String> {
    let loaded = LoadedMap {
        map: seed_map(),
        anchored_from_odom: Se2::IDENTITY,
        plane: None,
        geometry: None,
        report: None,
        grid: None,
    };
    let placement = Placement {
        convention,
        ..placement()
    };
    let (run, _) = loaded
        .correct(params, MatchMode::Fast, placement, poses, stamps_s)
        .map_err(|e| e.to_string())?;
    let _ = loaded.warnings(poses, stamps_s, convention, &run, &params);
    Ok(run)
}

/// Corrects poses that passed a reader's checks (their stamps, if the format has them) as the
/// command does: every output must be finite. The speed watch is also judged at rates other
/// than the preset's.
fn correct(poses: &[Pose3], stamps_s: Option<&[f64]>) -> Outcome {
    for rate_hz in [2.0, 100.0] {
        let _ = plausibility::speed_change_warning(poses, AxisConvention::Flu, rate_hz);
    }
    let run = correct_as_the_command_does(
        poses,
        stamps_s,
        harness_params(Preset::KissIcp, Method::Robust),
        AxisConvention::Flu,
    )?;
    assert!(
        run.iter().all(|c| c.pose.is_finite()),
        "a non-finite corrected pose from accepted input"
    );
    Ok(())
}

/// The source a snapshot harness's session belongs to: the orb-slam3 preset in the robust
/// method, whose sessions estimate the odometry's scale and watch for stalls, so that every part
/// of a snapshot is used.
pub fn snapshot_setup() -> SessionSetup {
    SessionSetup {
        map: seed_map(),
        grid: None,
        params: harness_params(Preset::OrbSlam3, Method::Robust),
        mode: MatchMode::Fast,
        placement: placement(),
        journal_dir: None,
        fingerprint: 7,
        persistence: None,
        daemon_epoch: 1,
    }
}

/// Restores a session whose journal holds the snapshot `bytes` (and the session header a
/// daemon writes), as a restarted daemon does; the restored session then answers the seed
/// drive and ends. Refusing the journal is a correct answer; a panic is the finding, and so
/// is an accepted answer that is not finite.
fn restored(bytes: &[u8]) -> Outcome {
    let err = |e: &dyn std::fmt::Display| e.to_string();
    // What the restore would refuse first, without the files (most mutants).
    journal::Snapshot::decode(bytes).ok_or("unreadable snapshot")?;
    let setup = snapshot_setup();
    let dir = tempfile::tempdir().map_err(|e| err(&e))?;
    let header = Header {
        session: 1,
        created_unix_ns: 1,
        fingerprint: setup.fingerprint,
    };
    std::fs::write(dir.path().join("session"), header.encode()).map_err(|e| err(&e))?;
    std::fs::write(dir.path().join("snapshot"), bytes).map_err(|e| err(&e))?;
    let mut session = session::restore(dir.path(), &setup).map_err(|e| err(&e))?;
    for (k, pose) in seeds::drive(20).iter().enumerate() {
        let stamp_ns = 1_000_000_000 + k as i64 * 100_000_000;
        let input = seeds::odom_pose(1, session.expected_seq(), stamp_ns, pose);
        let (handled, _) = session.handle(&input, 0, &setup, || false);
        keeps_the_contract(&handled.answer);
        session.watch_answered(&input, &handled.outcome);
    }
    session.watch.finish();
    Ok(())
}

/// Streams `bytes` (wire payloads, all taken as one session's) into a journaled session as the
/// daemon's worker does (a fresh start begins a new session and journal, a goodbye is skipped),
/// then restores the session from its journal and answers the seed drive with both. The restore
/// must succeed (nothing but the daemon wrote the journal), and the restored session must be the
/// one that wrote it: the same next number, state and watch, and the same answers bit for bit.
fn journaled(bytes: &[u8]) -> Outcome {
    let err = |e: &dyn std::fmt::Display| e.to_string();
    // In memory where there is a shared-memory file system: the journal syncs its header.
    let root = tempfile::tempdir_in("/dev/shm")
        .or_else(|_| tempfile::tempdir())
        .map_err(|e| err(&e))?;
    // The daemon's persistence thread writes the snapshot of each full segment and removes the
    // segments before the last full one; it ends, its work done, when the stream has ended.
    let (persistence, persisting) = lanealign_service::persistence::spawn().map_err(|e| err(&e))?;
    let streaming = SessionSetup {
        journal_dir: Some(root.path().to_path_buf()),
        persistence: Some(persistence),
        ..snapshot_setup()
    };
    let mut live: Option<Session> = None;
    for chunk in bytes.as_chunks::<ODOM_POSE_BYTES>().0 {
        let input = OdomPose {
            session: 1,
            ..seeds::odom_pose_from_bytes(chunk)
        };
        if input.flags & FLAG_END_SESSION != 0 {
            continue;
        }
        if live.is_none() || session::starts_afresh(&input) {
            let (session, failure) = Session::start(1, session::first_seq(&input), &streaming);
            if let Some(session::JournalFailure(e)) = failure {
                return Err(err(&e));
            }
            live = Some(session);
        }
        let Some(session) = live.as_mut() else {
            continue;
        };
        let (handled, _) = session.handle(&input, 0, &streaming, || false);
        keeps_the_contract(&handled.answer);
        session.watch_answered(&input, &handled.outcome);
        session.prepare(&streaming);
    }
    // Dropping the sender ends the persistence thread once its queue is done.
    let mut setup = streaming;
    setup.persistence = None;
    persisting
        .join()
        .map_err(|_| "the persistence thread panicked")?;
    let Some(mut wrote) = live else {
        return Err("no pose".into());
    };
    let dir = wrote.journal_dir().ok_or("no journal")?.to_path_buf();
    let mut restored = session::restore(&dir, &setup)
        .unwrap_or_else(|e| panic!("the daemon's own journal is not restored: {e}"));
    assert_eq!(
        restored.expected_seq(),
        wrote.expected_seq(),
        "the next number"
    );
    let state = |s: &Session| {
        journal::Snapshot {
            last_seq: 0,
            next_segment: 0,
            state: s.state(),
            watch: Some(s.watch.state()),
        }
        .encode()
    };
    assert!(state(&restored) == state(&wrote), "the restored state");
    for (k, pose) in seeds::drive(10).iter().enumerate() {
        let stamp_ns = 10_000_000_000 + k as i64 * 100_000_000;
        let input = seeds::odom_pose(1, wrote.expected_seq(), stamp_ns, pose);
        let (a, _) = wrote.handle(&input, 0, &setup, || false);
        let (b, _) = restored.handle(&input, 0, &setup, || false);
        let (a, b) = (a.answer, b.answer);
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert!(
            (a.status, a.expected_seq) == (b.status, b.expected_seq)
                && bits(&a.pose) == bits(&b.pose)
                && bits(&a.covariance) == bits(&b.covariance)
                && bits(&a.map_from_odom) == bits(&b.map_from_odom),
            "the restored session answers as the one that wrote its journal"
        );
    }
    Ok(())
}

/// Checks what docs/wire.md promises of an answer: a known status, and unless the answer is
/// flagged, a gap or passed through, a finite pose, correction, anchor rotation and scale, and
/// a covariance with no negative variance; returns the status.
fn keeps_the_contract(a: &payload::CorrectedPose) -> StatusCode {
    let status = StatusCode::from_code(a.status).expect("a known status");
    if !(status.is_flagged() || matches!(status, StatusCode::PassThrough | StatusCode::Gap)) {
        let numbers = a.pose.iter().chain(&a.map_from_odom).chain(&a.covariance);
        assert!(
            numbers
                .chain(&[a.anchor_yaw, a.odometry_scale, a.odometry_scale_sd])
                .all(|v| v.is_finite()),
            "a corrected answer ({status:?}) is finite: {a:?}"
        );
        let [xx, _, _, yy, _, yaw_yaw] = a.covariance;
        assert!(
            xx >= 0.0 && yy >= 0.0 && yaw_yaw >= 0.0,
            "a variance is negative: {a:?}"
        );
    }
    status
}

/// The source the wire harness's sessions belong to: the kiss-icp preset in the robust method
/// (the default method), without a journal.
pub fn wire_setup() -> SessionSetup {
    SessionSetup {
        map: seed_map(),
        grid: None,
        params: harness_params(Preset::KissIcp, Method::Robust),
        mode: MatchMode::Fast,
        placement: placement(),
        journal_dir: None,
        fingerprint: 0,
        persistence: None,
        daemon_epoch: 1,
    }
}

/// Serves a byte stream of payloads on `setup` as the worker does (a session starts at its first
/// pose or afresh on request, and ends at a goodbye; at most four at once), checking what every
/// answer must satisfy; returns each session's statuses in the order answered.
pub fn serve(bytes: &[u8], setup: &SessionSetup) -> BTreeMap<u64, Vec<StatusCode>> {
    let mut sessions: BTreeMap<u64, Session> = BTreeMap::new();
    let mut answered: BTreeMap<u64, Vec<StatusCode>> = BTreeMap::new();
    for chunk in bytes.as_chunks::<ODOM_POSE_BYTES>().0 {
        let input = seeds::odom_pose_from_bytes(chunk);
        if input.flags & FLAG_END_SESSION != 0 {
            sessions.remove(&input.session);
            continue;
        }
        let fresh = session::starts_afresh(&input);
        if fresh || !sessions.contains_key(&input.session) {
            if sessions.len() >= 4 && !sessions.contains_key(&input.session) {
                continue;
            }
            let first = session::first_seq(&input);
            sessions.insert(input.session, Session::start(input.session, first, setup).0);
        }
        let Some(session) = sessions.get_mut(&input.session) else {
            continue;
        };
        let before = session.expected_seq();
        let (handled, _) = session.handle(&input, 0, setup, || false);
        let a = handled.answer;
        assert_eq!(
            (a.session, a.seq),
            (input.session, input.seq),
            "answer names its input"
        );
        assert!(
            session.expected_seq() >= before,
            "the expected number never goes back"
        );
        let status = keeps_the_contract(&a);
        answered.entry(input.session).or_default().push(status);
    }
    answered
}

#[cfg(test)]
mod tests {
    use super::*;

    fn answer_on_the_seed_lanes() -> CorrectedPose {
        let mut corrector = twin(&seed_map(), MatchMode::Fast);
        let drive = seeds::drive(DRIVE_ALONG_POSES);
        drive
            .iter()
            .map(|pose| corrector.correct(pose).0)
            .last()
            .expect("a drive")
    }

    #[test]
    fn the_same_answer_passes_and_the_answer_to_no_pose_equals_itself() {
        let answer = answer_on_the_seed_lanes();
        assert!(matches!(answer.status, Status::Accepted { .. }));
        same_answer(0, &answer, &answer);
        let mut corrector = twin(&seed_map(), MatchMode::Fast);
        let (none, _) = corrector.correct(&Pose3::planar(f64::NAN, 0.0, 0.0, 0.0));
        assert!(none.covariance[0][0].is_nan());
        same_answer(0, &none, &none);
    }

    #[test]
    #[should_panic(expected = "corrections differ")]
    fn a_correction_a_nanometre_off_is_caught() {
        let answer = answer_on_the_seed_lanes();
        let mut off = answer;
        off.map_from_odom = Se2::new(0.0, 1e-9, 0.0) * answer.map_from_odom;
        same_answer(0, &answer, &off);
    }

    #[test]
    #[should_panic(expected = "covariances differ")]
    fn a_covariance_changed_in_its_last_digit_is_caught() {
        let answer = answer_on_the_seed_lanes();
        let mut off = answer;
        off.covariance[0][0] = f64::from_bits(off.covariance[0][0].to_bits() + 1);
        same_answer(0, &answer, &off);
    }
}
