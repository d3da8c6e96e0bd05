//! What the daemon tests share: a tile and a daemon configuration in a private namespace and
//! state folder, offline correction configured the same way, daemon processes, connections, and
//! a raw wire client for inputs the client library never sends.

#![allow(dead_code)] // each test file uses its own part of these helpers

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use lanealign_cli::daemon_config;
use lanealign_cli::daemon_process::DaemonProcess;
use lanealign_cli::kitti::anchors;
use lanealign_cli::synthetic;
use lanealign_client::connection::new_session_id;
use lanealign_client::Connection;
use lanealign_core::geo::{Anchor, Projection};
use lanealign_core::grid::{self, GridSpec};
use lanealign_core::lane_map::LaneMap;
use lanealign_core::params::{CorrectorConfig, Method, Preset};
use lanealign_core::pose::{apply_planar_correction, AxisConvention, Pose3};
use lanealign_core::se2::Se2;
use lanealign_core::source_corrector::{correct_stamped_trajectory, Placement};
use lanealign_core::tile;
use lanealign_map::compile::{compile, CompileOptions};
use lanealign_wire::clock::monotonic_ns;
use lanealign_wire::payload::{CorrectedPose, OdomPose, FLAG_END_SESSION};
use lanealign_wire::service::{Ipc, Namespace, PoseServices, SessionServices, MAX_NAMESPACE_LEN};
use lanealign_wire::wait::WaitStrategy;

/// A tile, a config with the given sources (name, anchor), and what offline correction needs.
pub struct Setup {
    pub dir: tempfile::TempDir,
    pub config: PathBuf,
    pub tile: PathBuf,
    pub namespace: String,
    pub state: PathBuf,
    pub convention: AxisConvention,
    pub anchors: Vec<(String, Anchor)>,
}

pub fn unique(name: &str) -> String {
    format!(
        "{name}-{}-{}",
        std::process::id(),
        monotonic_ns() % 1_000_000
    )
}

/// A namespace of its own for one test, as long as a namespace may be
/// ([`MAX_NAMESPACE_LEN`]): `<tag>`, zeros, `<pid>-<n>`. Every daemon test runs in the
/// longest namespace, whose iceoryx2 sockets have the longest paths.
pub fn unique_namespace(tag: char) -> String {
    let id = format!("{}-{}", std::process::id(), monotonic_ns() % 1_000_000);
    format!("{tag}{id:0>width$}", width = MAX_NAMESPACE_LEN - 1)
}

/// Removes a test's namespace files ([`lanealign_wire::service::Namespace::remove_files`]).
pub fn remove_namespace_files(namespace: &str) {
    if let Ok(namespace) = namespace.parse::<Namespace>() {
        let _ = namespace.remove_files();
    }
}

impl Drop for Setup {
    fn drop(&mut self) {
        remove_namespace_files(&self.namespace);
    }
}

/// Sources whose name starts with `busy` wait by busy-spinning, `spin` by spinning 200 us and
/// then blocking; others by events.
pub fn wait_of(name: &str) -> WaitStrategy {
    if name.starts_with("busy") {
        WaitStrategy::BusySpin { core: None }
    } else if name.starts_with("spin") {
        WaitStrategy::SpinThenBlock { spin_us: 200 }
    } else {
        WaitStrategy::Event
    }
}

/// Sources whose name starts with `smooth` are configured with smooth output, `pass` as
/// pass-through.
fn corrector(name: &str) -> CorrectorConfig {
    // Sources named `visual...` take the visual odometry preset, which estimates the scale.
    let preset = if name.starts_with("visual") {
        Preset::OrbSlam3
    } else {
        Preset::KissIcp
    };
    CorrectorConfig {
        smooth: name.starts_with("smooth"),
        ..CorrectorConfig::new(preset, Method::Robust)
    }
}

/// A setup whose daemon serves `daemon_map` (the tile, or a grid of it); offline correction
/// uses the tile.
fn write_setup(
    dir: tempfile::TempDir,
    tile_path: PathBuf,
    daemon_map: &Path,
    convention: AxisConvention,
    sources: Vec<(String, Anchor)>,
) -> Setup {
    let namespace = unique_namespace('t');
    let state = dir.path().join("state");
    let entries: Vec<daemon_config::Source> = sources
        .iter()
        .map(|(name, anchor)| daemon_config::Source {
            name: name.clone(),
            corrector: corrector(name),
            frame: convention,
            anchor: *anchor,
            pass_through: name.starts_with("pass"),
            wait: wait_of(name),
        })
        .collect();
    let config = dir.path().join("lanealignd.toml");
    daemon_config::write(
        &config,
        &daemon_config::config(daemon_map, &namespace, 1.0, &state, &entries),
    )
    .unwrap();
    Setup {
        dir,
        config,
        tile: tile_path,
        namespace,
        state,
        convention,
        anchors: sources,
    }
}

/// A tile of KITTI 07/08's map (one OSM extract) at 07's origin, and sources (name, sequence
/// whose anchor to use).
pub fn kitti_setup(data: &Path, sources: &[(&str, &str)]) -> Setup {
    kitti_setup_on(data, sources, None)
}

/// As [`kitti_setup`], with the daemon serving a grid of the tile's map in cells of
/// `cell_size_m` (margin 50 m) when given.
pub fn kitti_setup_on(data: &Path, sources: &[(&str, &str)], cell_size_m: Option<f64>) -> Setup {
    let all = anchors(data).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let origin = all["07"];
    let options = CompileOptions {
        origin: Some((origin.lat(), origin.lon())),
        projection: Projection::Kitti,
        ..CompileOptions::default()
    };
    let compiled = compile(&[data.join("osm/kitti_07.osm")], &options).unwrap();
    let tile_path = dir.path().join("07.tile");
    tile::write_bytes(&tile_path, &compiled.tile_bytes(3.0)).unwrap();
    let daemon_map = match cell_size_m {
        Some(cell_size_m) => {
            let folder = dir.path().join("grid");
            let spec = GridSpec {
                plane: &compiled.plane,
                spacing_m: 3.0,
                geometry: &compiled.geometry,
                cell_size_m,
                margin_m: 50.0,
                sign: None,
                map_version: 0,
            };
            grid::write(&folder, &compiled.map, &spec, 2).unwrap();
            folder
        }
        None => tile_path.clone(),
    };
    let sources = sources
        .iter()
        .map(|(name, seq)| (name.to_string(), all[*seq]))
        .collect();
    write_setup(
        dir,
        tile_path,
        &daemon_map,
        AxisConvention::KittiCamera,
        sources,
    )
}

/// Writes `map` (in the town's plane, with its lane geometry) as the tile `tile`.
pub fn write_town_tile(map: &LaneMap, tile: &Path) {
    let (plane, geometry) = (synthetic::town_plane(), synthetic::town_geometry());
    tile::write(tile, map, &plane, 3.0, &geometry).unwrap();
}

/// Writes `map` (in the town's plane) as the tile `tile` and, beside it, as the grid `grid`
/// of 100 m cells.
pub fn write_town_maps(map: &LaneMap, tile: &Path, grid: &Path) {
    write_town_tile(map, tile);
    write_town_grid(map, grid, 0);
}

/// Writes `map` (in the town's plane, with its lane geometry) as the grid `grid` of 100 m
/// cells, built as map version `map_version`.
pub fn write_town_grid(map: &LaneMap, grid: &Path, map_version: u64) {
    let (plane, geometry) = (synthetic::town_plane(), synthetic::town_geometry());
    let spec = GridSpec {
        plane: &plane,
        spacing_m: 3.0,
        geometry: &geometry,
        cell_size_m: 100.0,
        margin_m: 50.0,
        sign: None,
        map_version,
    };
    grid::write(grid, map, &spec, 2).unwrap();
}

/// The town's lanes moved 1 m north.
pub fn town_moved_north() -> LaneMap {
    let lanes: Vec<lanealign_core::lane_map::Lane> = synthetic::town_lanes()
        .into_iter()
        .map(|mut lane| {
            lane.points.iter_mut().for_each(|p| p[1] += 1.0);
            lane
        })
        .collect();
    LaneMap::new(&lanes).unwrap()
}

/// The synthetic town as a tile (for offline correction) and as a grid the daemon serves:
/// `town-grid`, a symbolic link to the folder `town-grid-1`.
pub fn town_grid_setup(sources: &[&str]) -> Setup {
    let dir = tempfile::tempdir().unwrap();
    let (tile_path, grid_path) = (dir.path().join("town.tile"), dir.path().join("town-grid"));
    let map = LaneMap::new(&synthetic::town_lanes()).unwrap();
    write_town_maps(&map, &tile_path, &dir.path().join("town-grid-1"));
    std::os::unix::fs::symlink("town-grid-1", &grid_path).unwrap();
    let sources = sources
        .iter()
        .map(|name| (name.to_string(), synthetic::town_anchor()))
        .collect();
    write_setup(dir, tile_path, &grid_path, AxisConvention::Flu, sources)
}

/// A tile of the synthetic town and sources on it.
pub fn town_setup(sources: &[&str]) -> Setup {
    let dir = tempfile::tempdir().unwrap();
    let tile_path = dir.path().join("town.tile");
    synthetic::write_town_tile(&tile_path).unwrap();
    let sources = sources
        .iter()
        .map(|name| (name.to_string(), synthetic::town_anchor()))
        .collect();
    let daemon_map = tile_path.clone();
    write_setup(dir, tile_path, &daemon_map, AxisConvention::Flu, sources)
}

/// What offline correction gives for `source`, configured as the daemon configures it.
pub fn offline(setup: &Setup, source: &str, poses: &[Pose3]) -> Vec<Pose3> {
    offline_stamped(setup, source, poses, None)
}

/// [`offline`] for poses stamped `stamps_s` (seconds).
pub fn offline_stamped(
    setup: &Setup,
    source: &str,
    poses: &[Pose3],
    stamps_s: Option<&[f64]>,
) -> Vec<Pose3> {
    offline_run(setup, source, poses, stamps_s)
        .into_iter()
        .map(|c| c.pose)
        .collect()
}

/// [`offline_stamped`]'s whole records: status, covariance, scale estimate.
pub fn offline_run(
    setup: &Setup,
    source: &str,
    poses: &[Pose3],
    stamps_s: Option<&[f64]>,
) -> Vec<lanealign_core::source_corrector::CorrectedPose> {
    offline_with_placement(setup, source, poses, stamps_s).0
}

/// [`offline`]'s poses and the status CSV `lanealign correct --status` writes for them, from
/// one run.
pub fn offline_with_status(setup: &Setup, source: &str, poses: &[Pose3]) -> (Vec<Pose3>, String) {
    let (run, placement) = offline_with_placement(setup, source, poses, None);
    let status = lanealign_cli::status_file::of_run(&run, &placement.anchored_from_odom);
    (run.into_iter().map(|c| c.pose).collect(), status)
}

fn offline_with_placement(
    setup: &Setup,
    source: &str,
    poses: &[Pose3],
    stamps_s: Option<&[f64]>,
) -> (
    Vec<lanealign_core::source_corrector::CorrectedPose>,
    Placement,
) {
    let (map, info) = tile::load(&setup.tile).unwrap();
    let anchor = setup.anchors.iter().find(|(n, _)| n == source).unwrap().1;
    let config = corrector(source);
    let placement = Placement {
        convention: setup.convention,
        anchored_from_odom: anchor.anchored_from_odom(&info.plane),
        smoothing: config.smoothing(),
    };
    let run = correct_stamped_trajectory(
        Arc::new(map),
        config.params().unwrap(),
        config.match_mode,
        placement,
        poses,
        stamps_s,
    );
    (run, placement)
}

/// Starts the daemon and waits until it is ready.
pub fn start(setup: &Setup) -> DaemonProcess {
    let log = setup.dir.path().join(format!("d-{}.log", monotonic_ns()));
    DaemonProcess::start_ready(&setup.config, &log, Duration::from_secs(20)).expect(
        "lanealignd must be built next to the tests (cargo test --workspace builds it) and start",
    )
}

pub fn namespace(setup: &Setup) -> Namespace {
    setup.namespace.parse().unwrap()
}

pub fn connect(setup: &Setup, source: &str) -> Connection {
    Connection::connect_in(
        &namespace(setup),
        &source.parse().unwrap(),
        new_session_id(),
    )
    .unwrap()
}

pub fn wait_for_daemon(conn: &mut Connection) {
    let until = Instant::now() + Duration::from_secs(10);
    while !conn.daemon_connected() && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(conn.daemon_connected(), "the daemon did not come up");
}

/// Publishes `pose` as the session's next and returns its answer, which must come within 5 s.
pub fn answer_of(conn: &mut Connection, pose: &Pose3) -> CorrectedPose {
    answer_stamped(conn, 0, pose)
}

/// [`answer_of`] for a pose stamped `stamp_ns` (ns).
pub fn answer_stamped(conn: &mut Connection, stamp_ns: i64, pose: &Pose3) -> CorrectedPose {
    conn.publish(stamp_ns, &pose.to_row_major()).unwrap();
    conn.recv(Duration::from_secs(5))
        .unwrap()
        .expect("an answer within 5 s")
}

/// Closes `conn` and waits until `daemon` has ended the session, the `before`-th its clients
/// closed (0-based): what a session's end tells is logged before it is said to have ended.
pub fn closed(conn: Connection, daemon: &DaemonProcess, before: usize) {
    assert!(conn.close(Duration::from_secs(5)).unwrap().daemon_told);
    let deadline = Instant::now() + Duration::from_secs(5);
    while daemon.log().matches("closed by its client").count() <= before {
        assert!(Instant::now() < deadline, "{}", daemon.log());
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// `daemon`'s log once it says `what`, or after 5 s. The log has a thread of its own: a record
/// made before an answer was sent may be written after the answer arrives.
pub fn log_once_it_says(daemon: &DaemonProcess, what: &str) -> String {
    let until = Instant::now() + Duration::from_secs(5);
    while !daemon.log().contains(what) && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(20));
    }
    daemon.log()
}

/// The one line of `log` that says `what` (panics, showing the log, unless exactly one does).
pub fn the_line_saying<'a>(log: &'a str, what: &str) -> &'a str {
    let lines: Vec<&str> = log.lines().filter(|l| l.contains(what)).collect();
    assert_eq!(lines.len(), 1, "lines saying {what:?}: {log}");
    lines[0]
}

/// The state folder of the daemon of `setup`'s namespace.
pub fn namespace_state(setup: &Setup) -> PathBuf {
    setup.state.join(&setup.namespace)
}

/// Where the daemon of `setup` records the newest map version it has served (the place
/// docs/operations.md names).
pub fn served_map_record(setup: &Setup) -> PathBuf {
    namespace_state(setup).join("served_map_version")
}

/// How many session journals the daemon of `setup` holds for `source`.
pub fn journal_count(setup: &Setup, source: &str) -> usize {
    std::fs::read_dir(namespace_state(setup).join(source))
        .map(|d| d.count())
        .unwrap_or(0)
}

/// The sequence numbers of the answers that `keep` keeps, in order.
pub fn seqs_where(answers: &[CorrectedPose], keep: impl Fn(&CorrectedPose) -> bool) -> Vec<u64> {
    answers.iter().filter(|a| keep(a)).map(|a| a.seq).collect()
}

/// The poses of `answers`.
pub fn poses_of(answers: &[CorrectedPose]) -> Vec<Pose3> {
    answers
        .iter()
        .map(|a| Pose3::from_row_major(&a.pose))
        .collect()
}

/// A client that talks the wire directly, to send what the client library never would.
pub struct RawClient {
    pub session: u64,
    publisher: iceoryx2::port::publisher::Publisher<Ipc, OdomPose, ()>,
    notifier: iceoryx2::port::notifier::Notifier<Ipc>,
    subscriber: iceoryx2::port::subscriber::Subscriber<Ipc, CorrectedPose, ()>,
    _poses: PoseServices<Ipc>,
    _answers: SessionServices<Ipc>,
    _node: iceoryx2::node::Node<Ipc>,
}

impl RawClient {
    pub fn new(setup: &Setup, source: &str) -> RawClient {
        let node = namespace(setup).node().unwrap();
        let source = source.parse().unwrap();
        let session = new_session_id();
        let poses = PoseServices::open(&node, &source).unwrap();
        let answers = SessionServices::open(&node, &source, session).unwrap();
        RawClient {
            session,
            publisher: poses.publisher().unwrap(),
            notifier: poses.notifier().unwrap(),
            subscriber: answers.subscriber().unwrap(),
            _poses: poses,
            _answers: answers,
            _node: node,
        }
    }

    /// Sends `pose` as `seq` and wakes the daemon, reading nothing; whether the daemon took it.
    pub fn send_only(&self, seq: u64, pose: [f64; 12]) -> bool {
        self.send_flagged(seq, pose, 0)
    }

    /// Sends the goodbye of this client's session ([`FLAG_END_SESSION`]) as `seq`, as the client
    /// library's `close` does; whether the daemon took it.
    pub fn goodbye(&self, seq: u64) -> bool {
        self.send_flagged(seq, [f64::NAN; 12], FLAG_END_SESSION)
    }

    fn send_flagged(&self, seq: u64, pose: [f64; 12], flags: u32) -> bool {
        let delivered = self
            .publisher
            .send_copy(OdomPose {
                session: self.session,
                seq,
                stamp_ns: 0,
                sent_mono_ns: monotonic_ns(),
                pose,
                flags,
                reserved: 0,
            })
            .unwrap();
        self.notifier.notify().unwrap();
        delivered == 1
    }

    /// Sends `pose` as `seq` and returns the answer.
    pub fn send(&self, seq: u64, pose: [f64; 12]) -> CorrectedPose {
        assert!(self.send_only(seq, pose), "the daemon takes the pose");
        let until = Instant::now() + Duration::from_secs(5);
        loop {
            if let Some(sample) = self.subscriber.receive().unwrap() {
                assert_eq!(sample.seq, seq);
                return *sample;
            }
            assert!(Instant::now() < until, "no answer to seq {seq}");
            std::thread::sleep(Duration::from_micros(200));
        }
    }
}

/// Every entry of /dev/shm, the namespaces' iceoryx2 folders included.
pub fn shm_entries() -> std::collections::BTreeSet<String> {
    let mut out = std::collections::BTreeSet::new();
    let mut stack = vec![PathBuf::from("/dev/shm")];
    while let Some(dir) = stack.pop() {
        for e in std::fs::read_dir(&dir).into_iter().flatten().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p.clone());
            }
            out.insert(p.display().to_string());
        }
    }
    out
}

/// Whether pose `i` of a drive made [`glitching`] is a glitch: every other pose from 50 on.
pub fn is_glitch(i: usize) -> bool {
    i >= 50 && i % 2 == 1
}

/// `poses` (planar) with each glitch ([`is_glitch`]) published 300 m to the side of the drive
/// and turned, the pose after it on the drive again.
pub fn glitching(poses: &[Pose3]) -> Vec<Pose3> {
    let aside = Se2::new(0.5, 0.0, 300.0);
    poses
        .iter()
        .enumerate()
        .map(|(i, p)| match is_glitch(i) {
            true => apply_planar_correction(&aside, p),
            false => *p,
        })
        .collect()
}
