//! Faults injected, not imagined: `kill -9` of clients and of the daemon at moments drawn from a
//! fixed seed, during real `lanealign replay` processes. Whatever is killed, a replay that runs
//! to its end writes exactly what offline correction gives, bit for bit, and exits 0: nothing
//! is lost, and no session inherits another's corrector. On the synthetic town always; on KITTI
//! 00 (real LiDAR odometry, the robust method) where `../shared/data` is present.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use common::*;
use lanealign_cli::daemon_config;
use lanealign_cli::daemon_process::DaemonProcess;
use lanealign_cli::synthetic::{self, Lcg};
use lanealign_client::Connection;
use lanealign_core::pose::{apply_planar_correction, Pose3};
use lanealign_core::se2::Se2;
use lanealign_core::trajectory::{read, write, Format, Trajectory};
use lanealign_tests::shared_data;
use lanealign_wire::clock::monotonic_ns;
use lanealign_wire::payload::{CorrectedPose, StatusCode, Warning};

static SERIAL: Mutex<()> = Mutex::new(());

/// A pause between `lo` and `hi` seconds: the same kill moments on every run.
fn between(rng: &mut Lcg, lo: f64, hi: f64) -> Duration {
    Duration::from_secs_f64(lo + (hi - lo) * rng.uniform())
}

/// `lanealign replay` of `input` into `output` as a process, its status CSV beside it
/// ([`status_of`]).
fn spawn_replay(setup: &Setup, source: &str, input: &Path, output: &Path, rate: &str) -> Child {
    Command::new(env!("CARGO_BIN_EXE_lanealign"))
        .args([
            "replay",
            "--source",
            source,
            "--namespace",
            &setup.namespace,
            "--rate",
            rate,
        ])
        .arg(input)
        .arg("-o")
        .arg(output)
        .arg("--status")
        .arg(status_of(output))
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Where [`spawn_replay`] writes the status CSV of `output`.
fn status_of(output: &Path) -> PathBuf {
    output.with_extension("csv")
}

fn finish(child: Child) -> String {
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "replay failed: {err}");
    err
}

fn daemon_log(setup: &Setup) -> PathBuf {
    setup.dir.path().join(format!("d-{}.log", monotonic_ns()))
}

/// Kills `daemon` (`kill -9`) and starts another on `setup`, which must restore a session.
fn killed_and_restored(daemon: DaemonProcess, setup: &Setup) -> DaemonProcess {
    daemon.kill().unwrap();
    let daemon = start(setup);
    assert!(
        daemon.log().contains("session restored"),
        "{}",
        daemon.log()
    );
    daemon
}

/// Kills `lanealign replay` clients at random moments, three times; then a replay runs to its
/// end. The killed sessions leave no trace in its output, the daemon cleans up after them, and
/// the replays that finished closed their sessions.
fn killed_clients(setup: &Setup, source: &str, input: &Path, poses: &[Pose3], seed: u64) {
    let daemon = start(setup);
    let mut rng = Lcg(seed);
    let mut finished = 0;
    for k in 0..3 {
        let mut doomed = spawn_replay(
            setup,
            source,
            input,
            &setup.dir.path().join(format!("killed-{k}.txt")),
            "2000",
        );
        std::thread::sleep(between(&mut rng, 0.2, 1.2));
        doomed.kill().unwrap();
        finished += usize::from(doomed.wait().unwrap().success());
    }
    let output = setup.dir.path().join("after-kills.txt");
    let summary = finish(spawn_replay(setup, source, input, &output, "max"));
    let got = read(&output, Format::Kitti).unwrap().poses;
    assert_eq!(got.len(), poses.len(), "{summary}");
    assert!(
        got == offline(setup, source, poses),
        "bit for bit after killed clients: {summary}"
    );
    // The replays that ran to their end closed their sessions (a doomed one may have finished
    // before its kill, or been killed after its goodbye).
    let until = Instant::now() + Duration::from_secs(5);
    let closed = || daemon.log().matches("closed by its client").count();
    while closed() < finished + 1 && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(
        (finished + 1..=4).contains(&closed()),
        "{} closed, {finished} of the doomed replays finished\n{}",
        closed(),
        daemon.log()
    );
    // The killed clients' nodes are cleaned up (by the daemon's supervisor or the next node
    // iceoryx2 creates): none is left dead.
    let config = namespace(setup).config();
    let until = Instant::now() + Duration::from_secs(5);
    let dead = || {
        let mut dead = 0;
        iceoryx2::node::Node::<lanealign_wire::service::Ipc>::list(&config, |state| {
            dead += matches!(state, iceoryx2::node::NodeState::Dead(_)) as usize;
            iceoryx2::prelude::CallbackProgression::Continue
        })
        .unwrap();
        dead
    };
    while dead() > 0 && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(50));
    }
    assert_eq!(dead(), 0, "dead nodes left");
    assert!(daemon.stop().unwrap());
}

/// Kills the daemon three times at random moments while one replay runs, restarting it each
/// time after a random pause (as systemd would). The replay exits 0 and its output equals an
/// uninterrupted offline run bit for bit. Returns the replay's summary.
fn killed_daemons(
    setup: &Setup,
    source: &str,
    input: &Path,
    poses: &[Pose3],
    seed: u64,
    rate: &str,
) -> String {
    let mut rng = Lcg(seed);
    let mut daemon = start(setup);
    let output = setup.dir.path().join("through-kills.txt");
    let client = spawn_replay(setup, source, input, &output, rate);
    let mut restored = 0;
    for _ in 0..3 {
        std::thread::sleep(between(&mut rng, 0.3, 1.0));
        daemon.kill().unwrap();
        std::thread::sleep(between(&mut rng, 0.0, 0.5));
        daemon =
            DaemonProcess::start_ready(&setup.config, &daemon_log(setup), Duration::from_secs(20))
                .unwrap();
        restored += daemon.log().contains("session restored") as usize;
    }
    let summary = finish(client);
    println!("{summary}");
    assert!(daemon.stop().unwrap());
    let got = read(&output, Format::Kitti).unwrap().poses;
    assert_eq!(got.len(), poses.len(), "{summary}");
    let (offline_poses, expected) = offline_with_status(setup, source, poses);
    assert!(
        got == offline_poses,
        "bit for bit through daemon kills: {summary}"
    );
    // Every answer's status, covariance and scale estimate too.
    let status = std::fs::read_to_string(status_of(&output)).unwrap();
    let differs = status
        .lines()
        .zip(expected.lines())
        .find(|(got, offline)| got != offline);
    assert!(
        status == expected,
        "the status CSV through daemon kills is offline's; first difference {differs:?}: {summary}"
    );
    assert!(
        summary.contains("3 daemon restarts"),
        "the client saw every restart: {summary}"
    );
    assert!(
        restored >= 2,
        "the session was restored from its journal ({restored} of 3 restarts)"
    );
    summary
}

/// A source on the synthetic town, its daemon setup (a tile, or a grid of 100 m cells), and two
/// laps of its odometry as a file.
struct Town {
    name: String,
    setup: Setup,
    input: PathBuf,
    poses: Vec<Pose3>,
}

fn town(setup_of: fn(&[&str]) -> Setup) -> Town {
    let (_, poses) = synthetic::drive(2, 7);
    town_driven(setup_of, poses)
}

fn town_driven(setup_of: fn(&[&str]) -> Setup, poses: Vec<Pose3>) -> Town {
    town_named("town", setup_of, poses)
}

/// [`town_driven`] for a source whose name starts with `prefix` (which chooses its corrector:
/// `common::corrector`).
fn town_named(prefix: &str, setup_of: fn(&[&str]) -> Setup, poses: Vec<Pose3>) -> Town {
    let name = unique(prefix);
    let setup = setup_of(&[&name]);
    let input = setup.dir.path().join("town-odometry.txt");
    write(
        &input,
        &Trajectory {
            stamps: None,
            poses: poses.clone(),
        },
        Format::Kitti,
    )
    .unwrap();
    Town {
        name,
        setup,
        input,
        poses,
    }
}

#[test]
fn killed_clients_leave_no_trace_on_the_town() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let t = town(town_setup);
    killed_clients(&t.setup, &t.name, &t.input, &t.poses, 11);
}

/// Always runs: on a source set for one session, an odometry process killed (`kill -9`) and
/// started again gets the place at once. The dead client's session gives it up as soon as the
/// daemon has removed what the client's node held (its supervisor looks every 500 ms), instead
/// of after three of the source's periods without a pose: set for 0.1 Hz (30 s), the new
/// session used to wait that long, its poses answered uncorrected (`sessions_full`).
#[test]
fn a_killed_clients_place_goes_to_the_next_client() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let t = town_named("orphan", town_setup, synthetic::drive(1, 42).1);
    let text = std::fs::read_to_string(&t.setup.config).unwrap();
    assert!(text.contains("max_sessions = 16\n") && text.ends_with("smooth = false\n"));
    let one_slow = text.replace("max_sessions = 16", "max_sessions = 1")
        + "\n[source.corrector.overrides]\nodometry_rate_hz = 0.1\n";
    std::fs::write(&t.setup.config, one_slow).unwrap();
    let daemon = start(&t.setup);
    let output = t.setup.dir.path().join("killed.txt");
    let mut doomed = spawn_replay(&t.setup, &t.name, &t.input, &output, "100");
    let deadline = Instant::now() + Duration::from_secs(10);
    while !daemon.log().contains("accepted=") {
        assert!(Instant::now() < deadline, "{}", daemon.log());
        std::thread::sleep(Duration::from_millis(20));
    }
    doomed.kill().unwrap();
    doomed.wait().unwrap();
    let killed = Instant::now();
    let mut next = connect(&t.setup, &t.name);
    wait_for_daemon(&mut next);
    let mut waited = 0;
    for pose in &t.poses {
        let answer = answer_of(&mut next, pose);
        if answer.status != StatusCode::PassThrough as u32 {
            break;
        }
        waited += 1;
        assert!(
            killed.elapsed() < Duration::from_secs(5),
            "still waiting 5 s after the kill ({waited} poses): {}",
            daemon.log()
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let log = log_once_it_says(&daemon, "its client is gone");
    assert!(log.contains("its client is gone"), "{log}");
    drop(next);
    drop(daemon);
}

/// Always runs: the daemon killed and restarted while its client has nothing in flight. The
/// idle client does not look for it (nothing is waiting for an answer); its next pose is
/// answered by the new daemon, which restored the session from its journal, and the client
/// sees the restart in that answer's daemon run: counted once, nothing sent again, every
/// answer equal to offline correction.
#[test]
fn a_daemon_restarted_between_poses_is_seen_in_its_answers() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("idle");
    let setup = town_setup(&[&name]);
    let mut daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let poses = &odometry[..600];
    let mut conn = connect(&setup, &name);
    wait_for_daemon(&mut conn);
    let mut answers: Vec<_> = poses[..300]
        .iter()
        .map(|p| answer_of(&mut conn, p))
        .collect();
    let idle = conn.events();
    daemon = killed_and_restored(daemon, &setup);
    assert_eq!(conn.events(), idle, "an idle client does nothing");
    answers.extend(poses[300..].iter().map(|p| answer_of(&mut conn, p)));
    let events = conn.events();
    assert!(
        poses_of(&answers) == offline(&setup, &name, poses),
        "{events:?}"
    );
    assert_eq!(
        (
            events.daemon_restarts,
            events.resent,
            events.duplicate_answers
        ),
        (1, 0, 0),
        "{events:?}"
    );
    assert!(daemon.stop().unwrap());
}

/// Always runs: a session that was sent a pose of NaNs (answered `invalid_input`, journaled
/// like every pose with a number) is restored after the daemon is killed, and goes on as
/// offline correction of the same poses does.
#[test]
fn a_journal_with_a_flagged_pose_is_restored() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("flagged");
    let setup = town_setup(&[&name]);
    let mut daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let mut poses = odometry[..600].to_vec();
    poses[150].translation[0] = f64::NAN;
    let mut conn = connect(&setup, &name);
    wait_for_daemon(&mut conn);
    let mut answers: Vec<_> = poses[..300]
        .iter()
        .map(|p| answer_of(&mut conn, p))
        .collect();
    assert_eq!(answers[150].status(), Some(StatusCode::InvalidInput));
    daemon.kill().unwrap();
    daemon = start(&setup);
    let log = daemon.log();
    assert!(
        log.contains("session restored") && !log.contains("not restored"),
        "{log}"
    );
    answers.extend(poses[300..].iter().map(|p| answer_of(&mut conn, p)));
    let events = conn.events();
    assert_eq!(events.fresh_starts, 0, "{events:?}");
    let expected = offline(&setup, &name, &poses);
    let same = |a: &Pose3, b: &Pose3| {
        let (a, b) = (a.to_row_major(), b.to_row_major());
        a.iter()
            .zip(&b)
            .all(|(x, y)| x == y || (x.is_nan() && y.is_nan()))
    };
    let got = poses_of(&answers);
    assert!(
        got.len() == expected.len() && got.iter().zip(&expected).all(|(a, b)| same(a, b)),
        "{events:?}"
    );
    assert!(daemon.stop().unwrap());
}

#[test]
fn killed_daemons_lose_nothing_on_the_town() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let t = town(town_setup);
    let summary = killed_daemons(&t.setup, &t.name, &t.input, &t.poses, 12, "800");
    assert!(
        !summary.contains("odometry scale"),
        "the kiss-icp preset does not estimate it: {summary}"
    );
}

/// The same with an odometry that restarts at its origin a third of the way: the sessions
/// restored after the jump continue the odometry from where the vehicle was, as offline.
#[test]
fn killed_daemons_lose_nothing_of_an_odometry_that_restarts() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let (_, mut poses) = synthetic::drive(2, 7);
    let at = poses.len() / 3;
    let origin = poses[at].to_se2().inverse();
    for pose in &mut poses[at..] {
        *pose = apply_planar_correction(&origin, pose);
    }
    let t = town_driven(town_setup, poses);
    // The odometry jumps; what it is corrected to does not.
    let out = offline(&t.setup, &t.name, &t.poses);
    let moved = |p: &[Pose3]| (p[at].translation - p[at - 1].translation).norm();
    assert!(moved(&t.poses) > 20.0, "{} m", moved(&t.poses));
    assert!(moved(&out) < 5.0, "{} m", moved(&out));
    killed_daemons(&t.setup, &t.name, &t.input, &t.poses, 14, "800");
}

/// The same with an odometry that glitches on every other pose (published 300 m to the side of
/// its drive, the next on it again): a session restored from a snapshot taken right after a
/// glitch (half of them) judges the pose after it from the frame before the glitch, as offline
/// (`LASNAP12`); the glitches taken for poses missing raise their warning in the answers.
#[test]
fn killed_daemons_lose_nothing_of_an_odometry_that_glitches() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let (_, poses) = synthetic::drive(2, 7);
    let t = town_driven(town_setup, glitching(&poses));
    // The glitches jump (but those that land ahead, taken for poses missing), and nothing else
    // does: the pose after each goes on in the drive's frame.
    let (_, status) = offline_with_status(&t.setup, &t.name, &t.poses);
    let jumps: Vec<usize> = status
        .lines()
        .skip(1)
        .enumerate()
        .filter(|(_, l)| l.contains("odometry_jump"))
        .map(|(i, _)| i)
        .collect();
    let glitches: Vec<usize> = (0..t.poses.len()).filter(|&i| is_glitch(i)).collect();
    assert!(jumps.iter().all(|&i| is_glitch(i)), "{jumps:?}");
    assert!(jumps.len() > glitches.len() / 2, "{jumps:?}");
    let summary = killed_daemons(&t.setup, &t.name, &t.input, &t.poses, 15, "800");
    // Those that landed ahead are raised in the answers through the kills, and replay says so.
    assert!(
        summary.contains("poses_missing from sequence number")
            && summary.contains("(a step of its odometry was longer than"),
        "{summary}"
    );
}

/// The same with an odometry that stalls (its steps 1 % of the road for 3 s, every 30 s of the
/// drive): the restored sessions watch its speed on from where the killed ones were, and every
/// covariance the stalls widen and every window they restart is offline's.
#[test]
fn killed_daemons_lose_nothing_of_an_odometry_that_stalls() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let t = town_driven(town_setup, stalled_town_drive());
    let out = offline_run(&t.setup, &t.name, &t.poses, None);
    let sd_m = |c: &lanealign_core::source_corrector::CorrectedPose| {
        (c.covariance[0][0] + c.covariance[1][1]).sqrt()
    };
    assert!(
        sd_m(&out[265]) < 10.0,
        "{} m before the first stall",
        sd_m(&out[265])
    );
    assert!(sd_m(&out[299]) > 20.0, "{} m after it", sd_m(&out[299]));
    killed_daemons(&t.setup, &t.name, &t.input, &t.poses, 16, "800");
}

/// Two laps of the town's odometry, stalled for 3 s every 30 s of the drive (from pose 270 on,
/// its steps 1 % of the road's).
fn stalled_town_drive() -> Vec<Pose3> {
    let (_, poses) = synthetic::drive(2, 7);
    let mut stalled = vec![poses[0]];
    for i in 1..poses.len() {
        let step = poses[i - 1].to_se2().inverse() * poses[i].to_se2();
        let step = if i % 300 >= 270 {
            let [x, y] = step.translation();
            Se2::new(step.yaw(), 0.01 * x, 0.01 * y)
        } else {
            step
        };
        let last = stalled[i - 1];
        stalled.push(apply_planar_correction(
            &(last.to_se2() * step * poses[i].to_se2().inverse()),
            &poses[i],
        ));
    }
    stalled
}

/// A session's warnings through daemon kills are those of a daemon that ran on. Its stamps
/// say 20 Hz (the source is set for 10) and its odometry stalls every 30 s. The daemon is
/// killed twice while the odometry's speed falls, before the fall is told: once restored from
/// the session's records from its first, once from a snapshot and the records after it. Each
/// restored session tells the fall under way once it ends, and does not tell again what was
/// told before (the rate its stamps say).
#[test]
fn a_restored_session_warns_as_if_its_daemon_had_run_on() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let t = town_driven(town_setup, stalled_town_drive()[..1300].to_vec());
    let stamp_ns = |i: usize| 1_700_000_000_000_000_000 + i as i64 * 50_000_000;
    let answer = |conn: &mut Connection, i: usize| answer_stamped(conn, stamp_ns(i), &t.poses[i]);
    // The warnings of session `id` in `log`, without their time and the session's id.
    let warnings = |log: &str, id: u64| -> Vec<String> {
        let id = format!("{id:016x}");
        log.lines()
            .filter(|l| l.contains(" WARN ") && l.contains(&id))
            .map(|l| l.split(" WARN ").nth(1).unwrap_or(l).replace(&id, "S"))
            .collect()
    };
    let mut daemon = start(&t.setup);
    let mut conn = connect(&t.setup, &t.name);
    wait_for_daemon(&mut conn);
    let ran_on = conn.session();
    for i in 0..t.poses.len() {
        answer(&mut conn, i);
    }
    closed(conn, &daemon, 0);
    let expected = warnings(&daemon.log(), ran_on);
    let falls: Vec<u64> = expected
        .iter()
        .filter(|w| w.contains("to_mps=0."))
        .filter_map(|w| w.split("seq=").nth(1)?.split(' ').next()?.parse().ok())
        .collect();
    assert_eq!(falls.len(), 4, "{expected:#?}");
    assert_eq!(
        expected.iter().filter(|w| w.contains("20 Hz")).count(),
        1,
        "{expected:#?}"
    );
    let mut conn = connect(&t.setup, &t.name);
    let killed = conn.session();
    let mut logs = Vec::new();
    let mut next = 0;
    // Killed two poses into the first fall (no snapshot yet: 512 records fill a segment) and
    // the second (after one).
    for fall_seq in &falls[..2] {
        let upto = *fall_seq as usize + 2;
        while next < upto {
            answer(&mut conn, next);
            next += 1;
        }
        // The log's writer runs on its own thread: what was told by now is written.
        std::thread::sleep(Duration::from_millis(300));
        let log = daemon.log();
        assert!(
            !warnings(&log, killed)
                .iter()
                .any(|w| w.contains(&format!("seq={fall_seq} "))),
            "killed before the fall at {fall_seq} was told: {log}"
        );
        logs.push(log);
        daemon = killed_and_restored(daemon, &t.setup);
    }
    while next < t.poses.len() {
        answer(&mut conn, next);
        next += 1;
    }
    closed(conn, &daemon, 0);
    logs.push(daemon.log());
    let got: Vec<String> = logs.iter().flat_map(|l| warnings(l, killed)).collect();
    assert_eq!(got, expected);
    assert!(daemon.stop().unwrap());
}

/// A session restored after its daemon was killed keeps the warning a pose raised after its last
/// snapshot: the town's drive paused for 30 poses on its straight and sent without stamps (the
/// pose after the pause, seq 201, a step taken for poses missing), the daemon killed two poses
/// later (no snapshot yet: the restore replays the session's records through its watch), and
/// every answer of the restored session carries `poses_missing`, as the killed one's did.
#[test]
fn a_restored_session_keeps_the_poses_missing_it_took() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let (_, odometry) = synthetic::drive(1, 42);
    let paused: Vec<Pose3> = odometry[..200]
        .iter()
        .chain(&odometry[230..300])
        .copied()
        .collect();
    let t = town_driven(town_setup, paused);
    let missing = |a: &CorrectedPose| a.warnings & Warning::PosesMissing.bit() != 0;
    let mut daemon = start(&t.setup);
    let mut conn = connect(&t.setup, &t.name);
    wait_for_daemon(&mut conn);
    for (i, pose) in t.poses[..203].iter().enumerate() {
        let answer = answer_of(&mut conn, pose);
        assert_eq!(missing(&answer), answer.seq > 201, "pose {i}");
    }
    daemon = killed_and_restored(daemon, &t.setup);
    for pose in &t.poses[203..] {
        let answer = answer_of(&mut conn, pose);
        assert!(missing(&answer), "seq {}", answer.seq);
    }
    closed(conn, &daemon, 0);
    assert!(daemon.stop().unwrap());
}

/// The same with a session that estimates its odometry's scale (the orb-slam3 preset; the town's
/// odometry 3 % long): the restored sessions continue the estimate, the odometry's steps scaled
/// so far and the covariance that carries the scale, as offline correction does.
#[test]
fn killed_daemons_lose_nothing_of_a_session_estimating_the_scale() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let (_, poses) = synthetic::drive(2, 7);
    let long: Vec<Pose3> = poses
        .iter()
        .map(|p| Pose3 {
            rotation: p.rotation,
            translation: p.translation * 1.03,
        })
        .collect();
    let t = town_named("visual", town_setup, long);
    let scale = offline_run(&t.setup, &t.name, &t.poses, None)
        .last()
        .map(|c| c.odometry_scale)
        .unwrap();
    println!("the scale estimate ends at {scale}");
    assert!(scale < 0.999, "the session estimates the scale: {scale}");
    let summary = killed_daemons(&t.setup, &t.name, &t.input, &t.poses, 15, "800");
    assert!(
        summary.contains(&format!(
            "odometry scale: steps multiplied by {scale:.4} at the end"
        )),
        "replay says the estimate as correct does: {summary}"
    );
}

/// The same on a grid: a restored session asks for its cells again and, behind the poses the
/// client sends again, waits for them; its answers equal offline correction on the whole tile.
#[test]
fn killed_daemons_lose_nothing_on_a_grid() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let t = town(town_grid_setup);
    killed_daemons(&t.setup, &t.name, &t.input, &t.poses, 13, "800");
}

/// A power loss, as hard as one can be: the daemon killed, and not one page of its mapped
/// journal segments on disk (every `.log` zeroed), only what the persistence thread synced: the
/// segments' copies, which hold every record up to the last second. The session is restored from
/// them, at the pose after their last record, and the replay still gets every pose answered (as
/// a fresh start: the daemon lost answers its client had).
#[test]
fn a_power_loss_restores_sessions_from_the_synced_copies() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Town {
        name,
        setup,
        input,
        poses,
    } = town(town_setup);
    let daemon = start(&setup);
    let output = setup.dir.path().join("through-power-loss.txt");
    let client = spawn_replay(&setup, &name, &input, &output, "800");
    std::thread::sleep(Duration::from_millis(2500));
    daemon.kill().unwrap();
    let mut last_copied = 0;
    let mut logs = Vec::new();
    files_named(&setup.state, "log", &mut logs);
    for log in &logs {
        let copy = lanealign_service::journal::copy_of(log);
        if copy.exists() {
            let records = lanealign_service::journal::read_segment(&copy).unwrap();
            let last = records.iter().map(|r| r.input.seq).max().unwrap_or(0);
            last_copied = last_copied.max(last);
        }
        let len = std::fs::metadata(log).unwrap().len() as usize;
        std::fs::write(log, vec![0; len]).unwrap();
    }
    assert!(
        !logs.is_empty() && last_copied > 0,
        "{} segments, last record copied {last_copied}",
        logs.len()
    );
    let daemon =
        DaemonProcess::start_ready(&setup.config, &daemon_log(&setup), Duration::from_secs(20))
            .unwrap();
    let restored = format!("next_seq={}", last_copied + 1);
    assert!(
        daemon.log().contains(&restored),
        "{restored} in {}",
        daemon.log()
    );
    let summary = finish(client);
    assert!(daemon.stop().unwrap());
    let got = read(&output, Format::Kitti).unwrap().poses;
    assert_eq!(got.len(), poses.len(), "{summary}");
}

/// The daemon's own state files are input too: killed three times, each time with every
/// session's journal damaged in another way before the restart (the session header cut short,
/// the first record of every segment and of its copy flipped, the snapshot overwritten with
/// random bytes), the daemon starts, says which journals it could not restore, and the replay
/// still gets every pose answered. A session that lost what its client had received starts
/// afresh, once per restart however many poses were in flight.
#[test]
fn tampered_journals_are_refused_and_every_pose_is_answered() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let t = town(town_setup);
    let mut rng = Lcg(31);
    let (mut daemon, client, output) = replay_on_town(&t, "800");
    let mut refused = 0;
    for (kind, what) in [
        ("session", "header cut short"),
        ("log", "first record flipped"),
        ("snapshot", "snapshot overwritten"),
    ] {
        // A snapshot is written once a segment is full (512 poses): wait for what is damaged.
        wait_for_files(&t.setup.state, kind);
        std::thread::sleep(between(&mut rng, 0.1, 0.4));
        daemon.kill().unwrap();
        for file in &wait_for_files(&t.setup.state, kind) {
            let mut bytes = std::fs::read(file).unwrap();
            match kind {
                "session" => bytes.truncate(bytes.len() / 2),
                "log" => {
                    let inside = lanealign_service::journal::RECORD_LEN / 2;
                    bytes[inside] ^= 0x5a;
                    let copy = lanealign_service::journal::copy_of(file);
                    if let Ok(mut copied) = std::fs::read(&copy) {
                        if let Some(b) = copied.get_mut(inside) {
                            *b ^= 0x5a;
                        }
                        std::fs::write(&copy, copied).unwrap();
                    }
                }
                _ => bytes
                    .iter_mut()
                    .for_each(|b| *b = (rng.uniform() * 256.0) as u8),
            }
            std::fs::write(file, bytes).unwrap();
        }
        daemon = DaemonProcess::start_ready(
            &t.setup.config,
            &daemon_log(&t.setup),
            Duration::from_secs(20),
        )
        .unwrap_or_else(|e| panic!("{what}: the daemon did not start: {e}"));
        refused += daemon.log().contains("a journal was not restored") as usize;
    }
    let (summary, _, _) = all_answered(&t, daemon, client, &output);
    assert!(refused >= 2, "{refused} of 3 restarts refused a journal");
    let fresh_starts = fresh_starts(&summary);
    assert!(
        summary.contains("3 daemon restarts") && (2..=3).contains(&fresh_starts),
        "one fresh start per restart that lost the session: {summary}"
    );
}

/// The map replaced while the daemon is down (a new tile installed between a crash and the
/// restart): a journal written under the old map is not replayed on the new one. The session
/// starts afresh once, and every pose is answered: as offline on the old map up to that pose,
/// and from there as an offline run on the new map that starts at it.
#[test]
fn a_daemon_restarted_on_another_map_starts_its_sessions_afresh() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let t = town(town_setup);
    restarted_without_the_journal(
        &t,
        || write_town_tile(&town_moved_north(), &t.setup.tile),
        "a journal was not restored",
    );
}

/// A journal an earlier daemon wrote (its session file of format 1, whose records lack the
/// odometry's scale) found at the restart, as after an upgrade: it is not restored, the log says
/// why, and the session starts afresh once. Every pose is answered: as offline up to that pose and
/// as an offline run that starts there after it.
#[test]
fn a_journal_of_an_earlier_format_starts_its_session_afresh() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let t = town(town_setup);
    let as_format_1 = || {
        for file in &wait_for_files(&t.setup.state, "session") {
            let mut bytes = std::fs::read(file).unwrap();
            bytes[..8].copy_from_slice(b"LASESS01");
            std::fs::write(file, bytes).unwrap();
        }
    };
    restarted_without_the_journal(&t, as_format_1, "written in an earlier journal format");
}

/// Replays the town, kills the daemon once its session has a snapshot, applies `while_down`, and
/// restarts it: its log must say `says` (why the journal was not restored), the session starts
/// afresh once, and every pose is answered: as offline correction of the whole run up to that
/// pose, and as an offline run on the tile as it now is from there.
fn restarted_without_the_journal(t: &Town, while_down: impl FnOnce(), says: &str) {
    let before = offline(&t.setup, &t.name, &t.poses);
    let (daemon, client, output) = replay_on_town(t, "800");
    wait_for_files(&t.setup.state, "snapshot");
    daemon.kill().unwrap();
    while_down();
    let daemon = DaemonProcess::start_ready(
        &t.setup.config,
        &daemon_log(&t.setup),
        Duration::from_secs(20),
    )
    .unwrap();
    let restart = daemon.log();
    let (summary, _, got) = all_answered(t, daemon, client, &output);
    assert!(restart.contains(says), "the log says {says:?}: {restart}");
    assert_eq!(fresh_starts(&summary), 1, "{summary}");
    let k = afresh_at(t, &got, &before, &summary);
    assert!(0 < k && k < got.len(), "{k}: {summary}");
}

/// A journal the disk loses (the session's folder removed while it streams, as a full or failing
/// state disk ends a journal) ends crash recovery for that session, not the session: the worker's
/// error is logged once, the persistence thread stops copying the lost segment (once logged), every
/// pose is answered exactly as offline, and the daemon stops cleanly.
#[test]
fn a_lost_journal_ends_crash_recovery_not_the_session() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let t = town(town_setup);
    let (daemon, client, output) = replay_on_town(&t, "800");
    let headers = wait_for_files(&t.setup.state, "session");
    let folder = headers
        .first()
        .and_then(|h| h.parent())
        .expect("the session's journal folder");
    std::fs::remove_dir_all(folder).unwrap();
    let (summary, log, got) = all_answered(&t, daemon, client, &output);
    assert_eq!(
        log.matches("journal write failed").count(),
        1,
        "the failure is logged once: {log}"
    );
    assert!(
        log.matches("syncing a journal segment's copy failed")
            .count()
            <= 1,
        "the persistence thread gives up on a copy that failed, not retries it every second: {log}"
    );
    assert!(
        got == offline(&t.setup, &t.name, &t.poses),
        "answered as offline: {summary}"
    );
}

/// A full state disk: the journals' folder on a 400 KiB file system (less than two segments and
/// their copies; the replay's journal needs about ten times that). The journal ends where the disk does, with an
/// error in the log, and never the daemon (its segments' space is allocated when they are made,
/// so no copy into a mapped page can meet a full disk). Killed after that and restarted on the
/// still-full disk (without the record of the map version served, which it cannot write and
/// says so), the daemon starts, and the replay gets every pose answered: as offline up to
/// the pose where the session, its journal behind what the client received, starts afresh (at
/// most once), and from there as an offline run that starts at that pose. Needs root (to mount the small
/// file system): visibly skipped otherwise.
#[test]
fn a_full_state_disk_ends_the_journal_not_the_daemon() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let t = town(town_setup);
    let Some(_disk) = SmallDisk::mount(&t.setup.state, "400k") else {
        println!("SKIPPED a_full_state_disk_ends_the_journal_not_the_daemon: needs root to mount a tmpfs");
        return;
    };
    let (mut daemon, client, output) = replay_on_town(&t, "800");
    let until = Instant::now() + Duration::from_secs(10);
    while !daemon.log().contains("journal write failed") && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(20));
    }
    // A metrics interval (1 s) and more: the daemon must go on serving and reporting.
    std::thread::sleep(Duration::from_millis(1500));
    let full = daemon.log();
    let after = full
        .split("journal write failed")
        .nth(1)
        .unwrap_or_else(|| {
            panic!(
                "the journal's end is logged (a daemon the full disk killed logs nothing): {full}"
            )
        });
    let record = full.lines().find(|l| l.contains("journal write failed"));
    assert!(
        record.is_some_and(|l| l.contains("No space left on device")),
        "one log line says what failed and why: {full}"
    );
    assert!(
        !after.contains("journal write failed") && after.contains("latency source"),
        "logged once, and the daemon serves on: {full}"
    );
    daemon.kill().unwrap();
    // The record of the map version served gone too, and the disk filled to the last byte: the
    // daemon cannot record the version it starts on, says so, and serves.
    std::fs::remove_file(served_map_record(&t.setup)).unwrap();
    let mut filler = std::fs::File::create(namespace_state(&t.setup).join("filler")).unwrap();
    while std::io::Write::write_all(&mut filler, &[0u8; 512]).is_ok() {}
    daemon = DaemonProcess::start_ready(
        &t.setup.config,
        &daemon_log(&t.setup),
        Duration::from_secs(20),
    )
    .unwrap_or_else(|e| panic!("the daemon did not start on a full disk: {e}\n{full}"));
    let unrecorded = "the map version served could not be recorded";
    assert!(
        daemon
            .log()
            .lines()
            .any(|l| l.contains(unrecorded) && l.contains("No space left on device")),
        "{}",
        daemon.log()
    );
    let (summary, log, got) = all_answered(&t, daemon, client, &output);
    let fresh_starts = fresh_starts(&summary);
    let k = afresh_at(&t, &got, &offline(&t.setup, &t.name, &t.poses), &summary);
    assert!(k > 0, "{summary}");
    assert_eq!(fresh_starts, usize::from(k < got.len()), "{summary}\n{log}");
}

/// A tmpfs of a given size mounted on a folder while it lives.
struct SmallDisk(PathBuf);

impl SmallDisk {
    /// Mounts a tmpfs of `size` (mount's notation) on `dir`, made if missing; `None` when this
    /// process may not mount.
    fn mount(dir: &Path, size: &str) -> Option<SmallDisk> {
        if !rustix::process::geteuid().is_root() {
            return None;
        }
        std::fs::create_dir_all(dir).unwrap();
        let mounted = Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"])
            .arg(dir)
            .status()
            .is_ok_and(|s| s.success());
        mounted.then(|| SmallDisk(dir.to_path_buf()))
    }
}

impl Drop for SmallDisk {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg("-l").arg(&self.0).status();
    }
}

/// Processes frozen mid-stream (SIGSTOP, then SIGCONT, as a debugger or a terminal's Ctrl-Z and
/// `fg` do) lose nothing: the daemon nine times, once for 1.2 s (the client holds back what comes
/// due meanwhile, more than the 512 poses it may keep in flight), then the client four times.
/// Every pose is answered once, equal to offline correction, nobody takes the interrupted sleeps
/// for a request to stop, and the daemon stops cleanly when asked.
#[test]
fn frozen_processes_answer_everything_when_they_run_again() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let t = town(town_setup);
    // 11.5 s of poses: every freeze below falls inside the replay.
    let (daemon, client, output) = replay_on_town(&t, "500");
    let freeze = |pid: u32, for_ms: u64| {
        for signal in ["-STOP", "-CONT"] {
            let status = Command::new("kill")
                .args([signal, &pid.to_string()])
                .status()
                .unwrap();
            assert!(status.success(), "kill {signal} {pid}");
            if signal == "-STOP" {
                std::thread::sleep(Duration::from_millis(for_ms));
            }
        }
    };
    // An interrupted sleep shows in about one freeze in six here: freeze often.
    for k in 0..9 {
        std::thread::sleep(Duration::from_millis(250));
        freeze(daemon.id(), if k == 4 { 1200 } else { 300 });
    }
    for _ in 0..4 {
        std::thread::sleep(Duration::from_millis(250));
        freeze(client.id(), 300);
    }
    let (summary, _, got) = all_answered(&t, daemon, client, &output);
    assert!(got == offline(&t.setup, &t.name, &t.poses), "{summary}");
    assert!(summary.contains("0 daemon restarts"), "{summary}");
}

/// Starts a daemon on `town`'s setup and a replay of its odometry at `rate` (Hz): the daemon, the
/// client and the file the client writes the answers to.
fn replay_on_town(town: &Town, rate: &str) -> (DaemonProcess, Child, PathBuf) {
    let daemon = start(&town.setup);
    let output = town.setup.dir.path().join("answers.txt");
    let client = spawn_replay(&town.setup, &town.name, &town.input, &output, rate);
    (daemon, client, output)
}

/// Waits for the replay `client`, stops `daemon` (which must exit cleanly) and asserts that every
/// pose of `town` came back in `output`: the client's summary, the daemon's log and the answers.
fn all_answered(
    town: &Town,
    daemon: DaemonProcess,
    client: Child,
    output: &Path,
) -> (String, String, Vec<Pose3>) {
    let summary = finish(client);
    println!("{summary}");
    let log = daemon.log();
    assert!(daemon.stop().unwrap(), "{log}");
    let got = read(output, Format::Kitti).unwrap().poses;
    assert_eq!(got.len(), town.poses.len(), "{summary}");
    (summary, log, got)
}

/// Where the answers `got` of a replay of `town` part from `before` (offline correction as the
/// session began), asserting that from there on they are offline correction of a run that starts
/// at that pose on the daemon's tile now: a session started afresh there. `got.len()` when they
/// never part.
fn afresh_at(town: &Town, got: &[Pose3], before: &[Pose3], summary: &str) -> usize {
    let k = got.iter().zip(before).take_while(|(a, b)| a == b).count();
    assert!(
        got[k..] == offline(&town.setup, &town.name, &town.poses[k..])[..],
        "from pose {k} on, as offline from there: {summary}"
    );
    k
}

/// The count of fresh session starts in a replay's summary.
fn fresh_starts(summary: &str) -> usize {
    summary
        .split([',', ';'])
        .find_map(|part| part.trim().strip_suffix(" fresh session starts"))
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no count of fresh starts in {summary}"))
}

/// The files below `dir` named `name` or ending with `.name`, waiting up to 20 s for one.
fn wait_for_files(dir: &Path, name: &str) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let until = Instant::now() + Duration::from_secs(20);
    files_named(dir, name, &mut found);
    while found.is_empty() && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(20));
        files_named(dir, name, &mut found);
    }
    assert!(!found.is_empty(), "no {name} file below {}", dir.display());
    found
}

/// Every file below `dir` named `name` or ending with `.name`.
fn files_named(dir: &Path, name: &str, found: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap().flatten() {
        let path = entry.path();
        if path.is_dir() {
            files_named(&path, name, found);
        } else if path.file_name().is_some_and(|n| n == name)
            || path.extension().is_some_and(|e| e == name)
        {
            found.push(path);
        }
    }
}

#[test]
fn killed_clients_leave_no_trace_on_kitti() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some(data) = shared_data() else { return };
    let name = unique("lidar07");
    let setup = kitti_setup(&data, &[(&name, "07")]);
    let input = data.join("odometry/lidar/07.txt");
    let poses = read(&input, Format::Kitti).unwrap().poses;
    killed_clients(&setup, &name, &input, &poses, 21);
}

#[test]
fn killed_daemons_lose_nothing_on_kitti() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some(data) = shared_data() else { return };
    let name = unique("lidar07");
    let setup = kitti_setup(&data, &[(&name, "07")]);
    let input = data.join("odometry/lidar/07.txt");
    let poses = read(&input, Format::Kitti).unwrap().poses;
    killed_daemons(&setup, &name, &input, &poses, 22, "150");
}

/// Overload over time, counted in and out: `lanealign soak` sends 10^6 poses over 8 sources
/// (2000 Hz each for 62.5 s) with correction and again in pass-through; every pose is answered,
/// and the daemon's resident memory does not grow with the poses it has served. Between a
/// quarter and three quarters of the run (500 000 poses) it may move by 10 % at most; to the
/// end by at most what the match caches may reserve (8 MiB a session) plus 10 %.
///
/// Not serial with the other tests: its two minutes are paced by the clock (about a third of
/// this 2-core machine busy), so it runs beside them, as a vehicle's other processes would.
#[test]
fn a_million_poses_over_eight_sources_lose_none_and_memory_stays_flat() {
    let out = Command::new(env!("CARGO_BIN_EXE_lanealign"))
        .args([
            "soak",
            "--sources",
            "8",
            "--rate",
            "2000",
            "--duration",
            "62.5",
        ])
        .args(["--waits", "event"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let namespace = daemon_config::run_namespace("soak", out.id()).unwrap();
    let out = out.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    println!("{stdout}");
    let rows: Vec<Vec<&str>> = stdout
        .lines()
        .filter(|l| l.starts_with("| correct") || l.starts_with("| pass-through"))
        .map(|l| l.trim_matches('|').split('|').map(str::trim).collect())
        .collect();
    assert_eq!(rows.len(), 2, "{stdout}");
    for row in rows {
        assert_eq!((row[3], row[4]), ("1000000", "0"), "{row:?}: poses, lost");
        let rss: Vec<f64> = row[8].split(" / ").map(|v| v.parse().unwrap()).collect();
        let [_, quarter, _, three_quarters, end] = rss[..] else {
            panic!("{row:?}: five memory readings");
        };
        assert!(
            three_quarters <= quarter * 1.1,
            "{row:?}: grew while serving"
        );
        assert!(
            end <= (quarter + 8.0 * 8192.0) * 1.1,
            "{row:?}: grew while serving"
        );
    }
    assert_eq!(
        namespace.files(),
        Vec::<PathBuf>::new(),
        "the soak's namespace files"
    );
}
