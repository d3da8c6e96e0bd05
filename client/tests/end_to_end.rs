//! End to end through the real daemon process and shared memory, on real KITTI data: answers
//! identical to offline correction, nothing lost, faults survived, bad input flagged.
//!
//! Needs `lanealignd` next to the test binaries (`cargo test --workspace` builds it) and
//! `../shared/data`. The tests share /dev/shm, so they run one at a time.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use lanealign_client::connection::{monotonic_ns, Connection};
use lanealign_client::daemon_process::DaemonProcess;
use lanealign_client::kitti::anchors;
use lanealign_client::replay::{replay, Rate};
use lanealign_client::wire::{pose_from_wire, pose_to_wire, OdomPose, WireStatus};
use lanealign_core::corrector::MatchMode;
use lanealign_core::geo::{Anchor, Projection};
use lanealign_core::offline::{correct, Source};
use lanealign_core::params::{Method, Preset};
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::smoothing::Smoothing;
use lanealign_core::tile;
use lanealign_core::trajectory::{read, Format};
use lanealign_map::compile::{compile, CompileOptions};

static SERIAL: Mutex<()> = Mutex::new(());

fn data() -> Option<PathBuf> {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data");
    if dir.join("osm/kitti_07.osm").is_file() {
        Some(dir)
    } else {
        eprintln!("SKIPPED: no shared data at {}", dir.display());
        None
    }
}

/// A tile of KITTI 07/08's map (one OSM extract) at 07's origin, a config with the given
/// sources (name, sequence whose anchor to use), and the anchors.
struct Setup {
    dir: tempfile::TempDir,
    config: PathBuf,
    tile: PathBuf,
    anchors: Vec<(String, Anchor)>,
}

fn setup(data: &Path, sources: &[(&str, &str)]) -> Setup {
    let all = anchors(data).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let origin = all["07"];
    let options = CompileOptions {
        origin: Some((origin.lat, origin.lon)),
        projection: Projection::Kitti,
        ..CompileOptions::default()
    };
    let (map, plane, _) = compile(&[data.join("osm/kitti_07.osm")], &options).unwrap();
    let tile_path = dir.path().join("07.tile");
    tile::write(&tile_path, &map, &plane, 3.0).unwrap();
    let mut text = format!(
        "tile = {:?}\nmetrics_interval_s = 1.0\n",
        tile_path.display().to_string()
    );
    let mut used = Vec::new();
    for (name, seq) in sources {
        let a = all[*seq];
        text.push_str(&format!(
            "\n[[source]]\nname = \"{name}\"\npreset = \"kiss-icp\"\nframe = \"kitti-camera\"\n\
             smooth = {}\n\
             anchor = {{ lat = {}, lon = {}, yaw_deg = {}, east_m = {}, north_m = {} }}\n",
            smoothed(name),
            a.lat,
            a.lon,
            a.yaw_deg,
            a.east_m,
            a.north_m
        ));
        used.push((name.to_string(), a));
    }
    let config = dir.path().join("lanealignd.toml");
    std::fs::write(&config, text).unwrap();
    Setup {
        dir,
        config,
        tile: tile_path,
        anchors: used,
    }
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

/// What offline correction gives for `source`: the daemon's default (robust) method, smoothed
/// when the source is.
fn offline(setup: &Setup, source: &str, poses: &[Pose3]) -> Vec<Pose3> {
    let (map, info) = tile::load(&setup.tile).unwrap();
    let anchor = setup.anchors.iter().find(|(n, _)| n == source).unwrap().1;
    let placement = Source {
        convention: AxisConvention::KittiCamera,
        plane_from_odom: anchor.plane_from_odom_in(&info.plane),
        smoothing: smoothed(source).then(Smoothing::default),
    };
    correct(
        Arc::new(map),
        Method::Robust.params(Preset::KissIcp),
        MatchMode::Fast,
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

#[test]
fn two_sources_at_once_match_offline_bit_for_bit_and_lose_nothing() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some(data) = data() else { return };
    let (a, b) = (unique("lidar07"), unique("smooth08"));
    let setup = setup(&data, &[(&a, "07"), (&b, "08")]);
    let daemon = start(&setup);
    let run = |name: String, seq: &'static str| {
        let path = data.join(format!("odometry/lidar/{seq}.txt"));
        std::thread::spawn(move || {
            let poses = read(&path, Format::Kitti).unwrap().poses;
            let conn = Connection::connect(&name).unwrap();
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
        let got: Vec<Pose3> = r.answers.iter().map(|x| pose_from_wire(&x.pose)).collect();
        assert!(
            want == got,
            "{name}: the daemon's poses equal offline correction bit for bit"
        );
        assert!(
            r.answers
                .iter()
                .filter(|x| x.status == WireStatus::Accepted as u32)
                .count()
                > 500
        );
    }
}

#[test]
fn bad_input_is_flagged_and_changes_nothing() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some(data) = data() else { return };
    let name = unique("bad");
    let setup = setup(&data, &[(&name, "07")]);
    let daemon = start(&setup);
    let poses = read(&data.join("odometry/lidar/07.txt"), Format::Kitti)
        .unwrap()
        .poses;
    let poses = &poses[..400];
    let conn = Connection::connect(&name).unwrap();
    let until = Instant::now() + Duration::from_secs(10);
    while !conn.daemon_connected() && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(10));
    }
    let flat = pose_to_wire;
    let send = |seq: u64, pose: [f64; 12]| {
        conn.publish(&OdomPose {
            seq,
            stamp_ns: 0,
            sent_mono_ns: monotonic_ns(),
            pose,
        })
        .unwrap();
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
        good.push(send(seq, flat(p)));
        if i == 200 {
            let mut nan = flat(p);
            nan[3] = f64::NAN;
            assert_eq!(send(seq + 1, nan).status, WireStatus::InvalidInput as u32);
            let mut inf = flat(p);
            inf[11] = f64::INFINITY;
            assert_eq!(send(seq + 2, inf).status, WireStatus::InvalidInput as u32);
            assert_eq!(
                send(seq + 2, flat(p)).status,
                WireStatus::DuplicateSeq as u32
            );
            assert_eq!(
                send(seq - 5, flat(p)).status,
                WireStatus::OutOfOrderSeq as u32
            );
        }
    }
    // Poses for a source the daemon does not serve are refused and counted.
    let stranger = Connection::connect(&unique("nobody")).unwrap();
    stranger
        .publish(&OdomPose {
            seq: 1,
            stamp_ns: 0,
            sent_mono_ns: monotonic_ns(),
            pose: flat(&poses[0]),
        })
        .unwrap();
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
    let got: Vec<Pose3> = good.iter().map(|x| pose_from_wire(&x.pose)).collect();
    assert!(want == got);
}

#[test]
fn a_killed_client_is_cleaned_up_and_others_are_unaffected() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some(data) = data() else { return };
    let (victim, survivor) = (unique("victim"), unique("survivor"));
    let setup = setup(&data, &[(&victim, "07"), (&survivor, "08")]);
    let daemon = start(&setup);
    let input = data.join("odometry/lidar/07.txt");
    let spawn_replay = |out: &str| {
        Command::new(env!("CARGO_BIN_EXE_lanealign"))
            .args(["replay", "--source", &victim, "--rate", "300"])
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
    let other = std::thread::spawn(move || {
        let conn = Connection::connect(&survivor_name).unwrap();
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
            .map(|x| pose_from_wire(&x.pose))
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
    let Some(data) = data() else { return };
    // iceoryx2 keeps machine-wide management state (created by the first node on a fresh
    // machine, kept by design): create it before looking, so that only what this test's
    // processes leave behind counts.
    drop(
        iceoryx2::prelude::NodeBuilder::new()
            .create::<iceoryx2::prelude::ipc::Service>()
            .unwrap(),
    );
    let before = shm_entries();
    let name = unique("restart");
    let setup = setup(&data, &[(&name, "07")]);
    let poses = read(&data.join("odometry/lidar/07.txt"), Format::Kitti)
        .unwrap()
        .poses;
    {
        let daemon = start(&setup);
        let conn = Connection::connect(&name).unwrap();
        let until = Instant::now() + Duration::from_secs(10);
        while !conn.daemon_connected() && Instant::now() < until {
            std::thread::sleep(Duration::from_millis(10));
        }
        let mut answered_before = 0;
        let mut answered_after = 0;
        let mut answered_last_before_stop = false;
        let mut daemon = Some(daemon);
        for (i, p) in poses.iter().enumerate().take(600) {
            let v = pose_to_wire(p);
            conn.publish(&OdomPose {
                seq: i as u64 + 1,
                stamp_ns: 0,
                sent_mono_ns: monotonic_ns(),
                pose: v,
            })
            .unwrap();
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
