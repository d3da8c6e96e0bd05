//! End to end through the real daemon process and shared memory: answers identical to offline
//! correction, nothing lost, faults survived, bad input flagged. On the synthetic town always,
//! on real KITTI data where `../shared/data` is present.
//!
//! Needs `lanealignd` next to the test binaries (`cargo test --workspace` builds it). Every test
//! runs in its own iceoryx2 namespace; they still run one at a time, to keep timing honest.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use lanealign_cli::daemon_config;
use lanealign_cli::daemon_process::DaemonProcess;
use lanealign_cli::kitti::anchors;
use lanealign_cli::replay::{replay, Rate};
use lanealign_cli::synthetic;
use lanealign_client::connection::new_session_id;
use lanealign_client::Connection;
use lanealign_core::geo::{Anchor, Projection};
use lanealign_core::params::{CorrectorConfig, Method, Preset};
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::source_corrector::{correct_trajectory, Placement};
use lanealign_core::tile;
use lanealign_core::trajectory::{read, Format};
use lanealign_map::compile::{compile, CompileOptions};
use lanealign_tests::shared_data;
use lanealign_wire::clock::monotonic_ns;
use lanealign_wire::payload::StatusCode;

static SERIAL: Mutex<()> = Mutex::new(());

/// A tile, a config with the given sources (name, anchor), and what offline correction needs.
struct Setup {
    dir: tempfile::TempDir,
    config: PathBuf,
    tile: PathBuf,
    namespace: String,
    convention: AxisConvention,
    anchors: Vec<(String, Anchor)>,
}

fn unique(name: &str) -> String {
    format!(
        "{name}-{}-{}",
        std::process::id(),
        monotonic_ns() % 1_000_000
    )
}

/// Sources whose name starts with `smooth` are configured with smooth output.
fn smoothed(name: &str) -> bool {
    name.starts_with("smooth")
}

fn corrector(name: &str) -> CorrectorConfig {
    CorrectorConfig {
        smooth: smoothed(name),
        ..CorrectorConfig::new(Preset::KissIcp, Method::Robust)
    }
}

fn write_setup(
    dir: tempfile::TempDir,
    tile_path: PathBuf,
    convention: AxisConvention,
    sources: Vec<(String, Anchor)>,
) -> Setup {
    let namespace = unique("test");
    let entries: Vec<daemon_config::Source> = sources
        .iter()
        .map(|(name, anchor)| daemon_config::Source {
            name: name.clone(),
            corrector: corrector(name),
            frame: convention,
            anchor: *anchor,
            pass_through: false,
        })
        .collect();
    let config = dir.path().join("lanealignd.toml");
    daemon_config::write(
        &config,
        &daemon_config::config(&tile_path, &namespace, 1.0, &entries),
    )
    .unwrap();
    Setup {
        dir,
        config,
        tile: tile_path,
        namespace,
        convention,
        anchors: sources,
    }
}

/// A tile of KITTI 07/08's map (one OSM extract) at 07's origin, and sources (name, sequence
/// whose anchor to use).
fn kitti_setup(data: &Path, sources: &[(&str, &str)]) -> Setup {
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
    let sources = sources
        .iter()
        .map(|(name, seq)| (name.to_string(), all[*seq]))
        .collect();
    write_setup(dir, tile_path, AxisConvention::KittiCamera, sources)
}

/// A tile of the synthetic town and sources on it.
fn town_setup(sources: &[&str]) -> Setup {
    let dir = tempfile::tempdir().unwrap();
    let tile_path = dir.path().join("town.tile");
    synthetic::write_town_tile(&tile_path).unwrap();
    let sources = sources
        .iter()
        .map(|name| (name.to_string(), synthetic::town_anchor()))
        .collect();
    write_setup(dir, tile_path, AxisConvention::Flu, sources)
}

/// What offline correction gives for `source`, configured as the daemon configures it.
fn offline(setup: &Setup, source: &str, poses: &[Pose3]) -> Vec<Pose3> {
    let (map, info) = tile::load(&setup.tile).unwrap();
    let anchor = setup.anchors.iter().find(|(n, _)| n == source).unwrap().1;
    let config = corrector(source);
    let placement = Placement {
        convention: setup.convention,
        anchored_from_odom: anchor.anchored_from_odom(&info.plane),
        smoothing: config.smoothing(),
    };
    correct_trajectory(
        Arc::new(map),
        config.params().unwrap(),
        config.match_mode,
        placement,
        poses,
    )
    .into_iter()
    .map(|c| c.pose)
    .collect()
}

fn start(setup: &Setup) -> DaemonProcess {
    DaemonProcess::start(&setup.config, &setup.dir.path().join(format!("d-{}.log", monotonic_ns()))).expect(
        "lanealignd must be built next to the tests: run `cargo test --workspace` or `cargo build -p lanealign-service` first",
    )
}

fn connect(setup: &Setup, source: &str) -> Connection {
    Connection::connect_in(
        &setup.namespace.parse().unwrap(),
        &source.parse().unwrap(),
        new_session_id(),
    )
    .unwrap()
}

fn wait_for_daemon(conn: &Connection) {
    let until = Instant::now() + Duration::from_secs(10);
    while !conn.daemon_connected() && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(10));
    }
    assert!(conn.daemon_connected(), "the daemon did not come up");
}

fn shm_entries() -> std::collections::BTreeSet<String> {
    let mut out = std::collections::BTreeSet::new();
    for root in ["/dev/shm", "/tmp/iceoryx2"] {
        let mut stack = vec![PathBuf::from(root)];
        while let Some(dir) = stack.pop() {
            for e in std::fs::read_dir(&dir).into_iter().flatten().flatten() {
                let p = e.path();
                if p.is_dir() {
                    stack.push(p.clone());
                }
                out.insert(p.display().to_string());
            }
        }
    }
    out
}

/// Always runs, data or not: two sessions on one source of the synthetic town, concurrently;
/// each gets every answer once, only its own, and equal to offline correction bit for bit.
#[test]
fn the_synthetic_town_through_the_daemon_equals_offline() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("town");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(2, 42);
    let run = |poses: Vec<Pose3>| {
        let (namespace, name) = (setup.namespace.clone(), name.clone());
        std::thread::spawn(move || {
            let conn = Connection::connect_in(
                &namespace.parse().unwrap(),
                &name.parse().unwrap(),
                new_session_id(),
            )
            .unwrap();
            replay(
                &conn,
                &name,
                &poses,
                &[],
                1,
                Rate::Max(16),
                Duration::from_secs(10),
            )
            .unwrap()
        })
    };
    // The second client drives the run backwards: its answers differ from the first's.
    let reversed: Vec<Pose3> = odometry.iter().rev().copied().collect();
    let (ha, hb) = (run(odometry.clone()), run(reversed.clone()));
    let (ra, rb) = (ha.join().unwrap(), hb.join().unwrap());
    assert!(daemon.stop().unwrap(), "clean exit");
    for (poses, r) in [(&odometry, &ra), (&reversed, &rb)] {
        let seqs: Vec<u64> = r.answers.iter().map(|x| x.seq).collect();
        assert_eq!(seqs, (1..=poses.len() as u64).collect::<Vec<_>>());
        let got: Vec<Pose3> = r
            .answers
            .iter()
            .map(|x| Pose3::from_row_major(&x.pose))
            .collect();
        assert!(offline(&setup, &name, poses) == got, "bit for bit");
        let accepted = r
            .answers
            .iter()
            .filter(|x| x.status() == Some(StatusCode::Accepted))
            .count();
        assert!(accepted > 1000, "{accepted} accepted");
    }
}

#[test]
fn two_sources_at_once_match_offline_bit_for_bit_and_lose_nothing() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some(data) = shared_data() else { return };
    let (a, b) = (unique("lidar07"), unique("smooth08"));
    let setup = kitti_setup(&data, &[(&a, "07"), (&b, "08")]);
    let daemon = start(&setup);
    let run = |name: String, seq: &'static str| {
        let path = data.join(format!("odometry/lidar/{seq}.txt"));
        let namespace = setup.namespace.clone();
        std::thread::spawn(move || {
            let poses = read(&path, Format::Kitti).unwrap().poses;
            let conn = Connection::connect_in(
                &namespace.parse().unwrap(),
                &name.parse().unwrap(),
                new_session_id(),
            )
            .unwrap();
            let r = replay(
                &conn,
                &name,
                &poses,
                &[],
                1,
                Rate::Max(32),
                Duration::from_secs(10),
            )
            .unwrap();
            (poses, r)
        })
    };
    let (ha, hb) = (run(a.clone(), "07"), run(b.clone(), "08"));
    let (poses_a, ra) = ha.join().unwrap();
    let (poses_b, rb) = hb.join().unwrap();
    assert!(daemon.stop().unwrap(), "clean exit");
    for (name, poses, r) in [(&a, &poses_a, &ra), (&b, &poses_b, &rb)] {
        let seqs: Vec<u64> = r.answers.iter().map(|x| x.seq).collect();
        assert_eq!(
            seqs,
            (1..=poses.len() as u64).collect::<Vec<_>>(),
            "{name}: every pose once, in order"
        );
        let want = offline(&setup, name, poses);
        let got: Vec<Pose3> = r
            .answers
            .iter()
            .map(|x| Pose3::from_row_major(&x.pose))
            .collect();
        assert!(
            want == got,
            "{name}: the daemon's poses equal offline correction bit for bit"
        );
        assert!(
            r.answers
                .iter()
                .filter(|x| x.status() == Some(StatusCode::Accepted))
                .count()
                > 500
        );
    }
}

/// Always runs: non-finite poses and duplicate or out-of-order sequence numbers come back
/// flagged and change nothing; poses for an unconfigured source are refused and counted.
#[test]
fn bad_input_is_flagged_and_changes_nothing() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("bad");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let poses = &odometry[..400];
    let conn = connect(&setup, &name);
    wait_for_daemon(&conn);
    let send = |seq: u64, pose: [f64; 12]| {
        conn.publish(seq, 0, &pose).unwrap();
        let answer = conn
            .recv(Duration::from_secs(5))
            .unwrap()
            .expect("an answer");
        assert_eq!(answer.seq, seq);
        answer
    };
    let mut good = Vec::new();
    for (i, p) in poses.iter().enumerate() {
        let seq = 10 * (i as u64 + 1);
        good.push(send(seq, p.to_row_major()));
        if i == 200 {
            let mut nan = p.to_row_major();
            nan[3] = f64::NAN;
            assert_eq!(send(seq + 1, nan).status(), Some(StatusCode::InvalidInput));
            let mut inf = p.to_row_major();
            inf[11] = f64::INFINITY;
            assert_eq!(send(seq + 2, inf).status(), Some(StatusCode::InvalidInput));
            assert_eq!(
                send(seq + 2, p.to_row_major()).status(),
                Some(StatusCode::DuplicateSeq)
            );
            assert_eq!(
                send(seq - 5, p.to_row_major()).status(),
                Some(StatusCode::OutOfOrderSeq)
            );
        }
    }
    // Poses for a source the daemon does not serve are refused and counted.
    let stranger = connect(&setup, &unique("nobody"));
    stranger.publish(1, 0, &poses[0].to_row_major()).unwrap();
    let until = Instant::now() + Duration::from_secs(5);
    while !daemon.log().contains("refused") && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(
        daemon.log().contains("not configured are refused")
            && daemon.log().contains("refused_sources=1"),
        "{}",
        daemon.log()
    );
    assert!(
        stranger.recv(Duration::from_millis(200)).unwrap().is_none(),
        "no answer for an unknown source"
    );
    // The per-source metrics split the corrector's time into matching, ICP and bookkeeping.
    let until = Instant::now() + Duration::from_secs(5);
    while !daemon.log().contains("bookkeeping_p99_us") && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(50));
    }
    let log = daemon.log();
    assert!(
        [
            "matching_p99_us",
            "icp_p99_us",
            "bookkeeping_p99_us",
            "e2e_p999_us",
            "daemon_p999_us"
        ]
        .iter()
        .all(|k| log.contains(k)),
        "{log}"
    );
    drop((conn, stranger));
    assert!(daemon.stop().unwrap());
    // The flagged inputs changed nothing: the good answers equal offline correction of the good
    // poses alone.
    let want = offline(&setup, &name, poses);
    let got: Vec<Pose3> = good
        .iter()
        .map(|x| Pose3::from_row_major(&x.pose))
        .collect();
    assert!(want == got);
}

#[test]
fn a_killed_client_is_cleaned_up_and_others_are_unaffected() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some(data) = shared_data() else { return };
    let (victim, survivor) = (unique("victim"), unique("survivor"));
    let setup = kitti_setup(&data, &[(&victim, "07"), (&survivor, "08")]);
    let daemon = start(&setup);
    let input = data.join("odometry/lidar/07.txt");
    let spawn_replay = |out: &str| {
        Command::new(env!("CARGO_BIN_EXE_lanealign"))
            .args([
                "replay",
                "--source",
                &victim,
                "--namespace",
                &setup.namespace,
            ])
            .args(["--rate", "300"])
            .arg(&input)
            .arg("-o")
            .arg(setup.dir.path().join(out))
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    let mut doomed = spawn_replay("killed.txt");
    let survivor_poses = read(&data.join("odometry/lidar/08.txt"), Format::Kitti)
        .unwrap()
        .poses;
    let survivor_name = survivor.clone();
    let poses = survivor_poses.clone();
    let namespace = setup.namespace.clone();
    let other = std::thread::spawn(move || {
        let conn = Connection::connect_in(
            &namespace.parse().unwrap(),
            &survivor_name.parse().unwrap(),
            new_session_id(),
        )
        .unwrap();
        replay(
            &conn,
            &survivor_name,
            &poses,
            &[],
            1,
            Rate::Hz(1000.0),
            Duration::from_secs(10),
        )
        .unwrap()
    });
    std::thread::sleep(Duration::from_millis(1500));
    doomed.kill().unwrap();
    doomed.wait().unwrap();
    let r = other.join().unwrap();
    assert_eq!(
        r.answers.len(),
        survivor_poses.len(),
        "the other client lost nothing"
    );
    let want = offline(&setup, &survivor, &survivor_poses);
    assert!(
        want == r
            .answers
            .iter()
            .map(|x| Pose3::from_row_major(&x.pose))
            .collect::<Vec<_>>()
    );
    // The supervisor removes the dead client's node.
    let until = Instant::now() + Duration::from_secs(5);
    while !daemon
        .log()
        .contains("removed the resources of a dead node")
        && Instant::now() < until
    {
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(
        daemon
            .log()
            .contains("removed the resources of a dead node"),
        "{}",
        daemon.log()
    );
    // The killed client restarts (its sequence numbers start over) and runs to the end.
    let restarted = spawn_replay("restarted.txt").wait_with_output().unwrap();
    assert!(
        restarted.status.success(),
        "{}",
        String::from_utf8_lossy(&restarted.stderr)
    );
    let out = read(&setup.dir.path().join("restarted.txt"), Format::Kitti).unwrap();
    assert_eq!(out.poses.len(), 1101);
    assert!(daemon.stop().unwrap());
}

#[test]
fn the_daemon_restarts_under_a_publishing_client_and_leaves_no_shared_memory() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some(data) = shared_data() else { return };
    let name = unique("restart");
    let setup = kitti_setup(&data, &[(&name, "07")]);
    // iceoryx2 keeps per-namespace management state (created by the namespace's first node,
    // kept by design): create it before looking, so that only what this test's processes leave
    // behind counts.
    let namespace: lanealign_wire::service::Namespace = setup.namespace.parse().unwrap();
    drop(namespace.node().unwrap());
    let before = shm_entries();
    let poses = read(&data.join("odometry/lidar/07.txt"), Format::Kitti)
        .unwrap()
        .poses;
    {
        let daemon = start(&setup);
        let conn = connect(&setup, &name);
        wait_for_daemon(&conn);
        let mut answered_before = 0;
        let mut answered_after = 0;
        let mut answered_last_before_stop = false;
        let mut daemon = Some(daemon);
        for (i, p) in poses.iter().enumerate().take(600) {
            conn.publish(i as u64 + 1, 0, &p.to_row_major()).unwrap();
            if i == 200 {
                // Stop the daemon while the client goes on publishing, then start it again.
                assert!(daemon.take().unwrap().stop().unwrap());
            }
            if i == 300 {
                daemon = Some(start(&setup));
            }
            std::thread::sleep(Duration::from_millis(3));
            while let Some(a) = conn.try_recv().unwrap() {
                answered_last_before_stop |= a.seq == 201;
                if a.seq <= 200 {
                    answered_before += 1;
                } else {
                    answered_after += 1;
                }
            }
        }
        let until = Instant::now() + Duration::from_secs(2);
        while Instant::now() < until {
            if let Some(a) = conn.recv(Duration::from_millis(100)).unwrap() {
                answered_after += (a.seq > 200) as usize;
            }
        }
        assert_eq!(
            answered_before, 200,
            "every pose before the restart is answered"
        );
        assert!(
            answered_last_before_stop,
            "SIGTERM drains: the pose published just before it is answered"
        );
        assert!(
            answered_after > 200,
            "the restarted daemon serves the same client: {answered_after}"
        );
        drop(conn);
        assert!(
            daemon.take().unwrap().stop().unwrap(),
            "clean exit on SIGTERM"
        );
    }
    let after = shm_entries();
    let left: Vec<_> = after.difference(&before).collect();
    assert!(
        left.is_empty(),
        "shared memory or iceoryx2 files left behind: {left:?}"
    );
}
