//! lanealignd through its real process and shared memory: sessions get correctors of their own
//! and only their own answers, answers equal offline correction bit for bit, bad input is
//! flagged and changes nothing, a client that never reads holds up no one, one daemon per
//! namespace, a source that cannot start stops the daemon, SIGHUP reloads the tile for new
//! sessions (and refuses a bad one), nothing is left in shared memory, neither a cleaner of
//! `/tmp` nor a private `/tmp` cuts a client off, a stop request survives the SIGCONT after it,
//! a log nobody reads holds up no answer, one connection serves a publishing thread and a
//! receiving one, a daemon of another version is named at once. Every test's namespace is as
//! long as a namespace may be. On the synthetic town always; on real KITTI data where
//! `../shared/data` is present.

mod common;

use std::os::unix::net::UnixDatagram;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use common::*;
use lanealign_cli::daemon_process::{daemon_binary, DaemonProcess, DaemonProcessError};
use lanealign_cli::replay::{replay, waited_for_place_warning, Rate};
use lanealign_cli::synthetic;
use lanealign_client::connection::new_session_id;
use lanealign_client::Connection;
use lanealign_core::pose::{AxisConvention, Pose3};
use lanealign_core::trajectory::{
    quaternion_from_rotation, read, rotation_from_quaternion, Format,
};
use lanealign_service::cpu_latency;
use lanealign_tests::shared_data;
use lanealign_wire::payload::{CorrectedPose, ReasonCode, StatusCode, Warning};
use lanealign_wire::service::{Ipc, DAEMON_NODE, WIRE_VERSION};
use rustix::process::Signal;

/// The tests start daemons and count shared-memory files: one at a time.
static SERIAL: Mutex<()> = Mutex::new(());

/// True when this process runs as root and has each of `tools`; otherwise says on stderr that
/// `test` is skipped and why, so that it is visible.
fn root_with(test: &str, tools: &[&str]) -> bool {
    let missing: Vec<&str> = tools
        .iter()
        .copied()
        .filter(|t| Command::new(t).arg("--help").output().is_err())
        .collect();
    if rustix::process::geteuid().is_root() && missing.is_empty() {
        return true;
    }
    skipped(test, &format!("needs root and {}", tools.join(", ")));
    false
}

/// Says on the terminal, past the harness's capture of passing tests, that `test` is skipped
/// and why.
fn skipped(test: &str, why: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "SKIPPED {test}: {why}");
}

/// A new session on `source` of the daemon of `setup`, once the daemon serves it and has
/// answered `first`.
fn served(setup: &Setup, source: &str, first: &Pose3) -> Connection {
    let mut client = connect(setup, source);
    wait_for_daemon(&mut client);
    answer_of(&mut client, first);
    client
}

/// Sends `sig` to process `pid`.
fn signal(pid: u32, sig: Signal) {
    let pid = rustix::process::Pid::from_raw(pid as i32).expect("a child's pid is positive");
    rustix::process::kill_process(pid, sig).unwrap();
}

/// Writes `poses` to `path` as a KITTI trajectory.
fn write_kitti(path: &std::path::Path, poses: &[Pose3]) {
    let trajectory = lanealign_core::trajectory::Trajectory {
        stamps: None,
        poses: poses.to_vec(),
    };
    lanealign_core::trajectory::write(path, &trajectory, Format::Kitti).unwrap();
}

/// A session of `source` that replayed `poses` (stamped `stamps` in nanoseconds, none when
/// empty) at `rate`: the answers, and the connection, still open.
fn replay_session(
    setup: &Setup,
    source: &str,
    poses: &[Pose3],
    stamps: &[i64],
    rate: Rate,
) -> (Vec<CorrectedPose>, Connection) {
    let mut conn = connect(setup, source);
    let r = replay(
        &mut conn,
        source,
        poses,
        stamps,
        rate,
        Duration::from_secs(10),
        Duration::from_secs(10),
    )
    .unwrap();
    (r.answers, conn)
}

fn run_replay(setup: &Setup, source: &str, poses: &[Pose3], rate: Rate) -> Vec<Pose3> {
    let (answers, _) = replay_session(setup, source, poses, &[], rate);
    let seqs: Vec<u64> = answers.iter().map(|x| x.seq).collect();
    assert_eq!(
        seqs,
        (1..=poses.len() as u64).collect::<Vec<_>>(),
        "every pose once, in order"
    );
    poses_of(&answers)
}

/// The shared LiDAR odometry run of sequence `seq`.
fn lidar_run(data: &std::path::Path, seq: &str) -> Vec<Pose3> {
    let path = data.join(format!("odometry/lidar/{seq}.txt"));
    read(&path, Format::Kitti).unwrap().poses
}

/// Two sources replayed at once, each in a session of its own; their answers.
fn replay_two(
    setup: &Setup,
    (a, poses_a): (&str, &[Pose3]),
    (b, poses_b): (&str, &[Pose3]),
    rate: Rate,
) -> (Vec<Pose3>, Vec<Pose3>) {
    std::thread::scope(|s| {
        let ha = s.spawn(|| run_replay(setup, a, poses_a, rate));
        let hb = s.spawn(|| run_replay(setup, b, poses_b, rate));
        (ha.join().unwrap(), hb.join().unwrap())
    })
}

/// Always runs: two sessions on one source of the synthetic town, at once; each gets every
/// answer once, only its own, equal to offline correction bit for bit; and a third session
/// later starts from a fresh corrector.
#[test]
fn sessions_have_their_own_correctors_and_answers() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("town");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(2, 42);
    // The second client drives the run backwards: its answers differ from the first's.
    let reversed: Vec<Pose3> = odometry.iter().rev().copied().collect();
    let (forward, backward) = std::thread::scope(|s| {
        let a = s.spawn(|| run_replay(&setup, &name, &odometry, Rate::Max(16)));
        let b = s.spawn(|| run_replay(&setup, &name, &reversed, Rate::Max(16)));
        (a.join().unwrap(), b.join().unwrap())
    });
    assert!(forward == offline(&setup, &name, &odometry), "bit for bit");
    assert!(backward == offline(&setup, &name, &reversed), "bit for bit");
    // A later session on the same source starts afresh: it does not inherit a corrector.
    let again = run_replay(&setup, &name, &odometry[..1500], Rate::Max(32));
    assert!(again == offline(&setup, &name, &odometry[..1500]));
    assert!(daemon.stop().unwrap(), "clean exit");
}

/// Always runs: a session whose stamps say 100 Hz on a source set for the presets' 10 Hz is
/// answered as before, and the daemon's log says once which setting fits it.
#[test]
fn a_source_faster_than_its_corrector_is_set_for_is_told_in_the_log() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("fast");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(2, 42);
    let poses = &odometry[..300];
    let stamps: Vec<i64> = (0..300)
        .map(|i| 1_700_000_000_000_000_000 + i * 10_000_000)
        .collect();
    let mut conn = connect(&setup, &name);
    let r = replay(
        &mut conn,
        &name,
        poses,
        &stamps,
        Rate::Max(16),
        Duration::from_secs(10),
        Duration::from_secs(10),
    )
    .unwrap();
    assert!(
        poses_of(&r.answers) == offline(&setup, &name, poses),
        "bit for bit"
    );
    // The warning is written after the 64th answer is sent, before the 65th pose is taken; in
    // the log for sure once the session's end is (the log has a thread of its own).
    closed(conn, &daemon, 0);
    let log = daemon.log();
    let told = log.matches("the poses come at about 100 Hz").count();
    assert_eq!(told, 1, "{log}");
    assert!(log.contains("set odometry_rate_hz = 100"), "{log}");
    assert!(daemon.stop().unwrap(), "clean exit");
}

/// Always runs: an odometry that paused for 3 s (30 m of the town's road), with its stamps, is
/// corrected as offline with them (no jump). Without stamps (the replay's are the poses'
/// indices) the pause reads as poses missing: on a straight the step drives on and is motion;
/// over a corner it turns unlike the road and is taken for a jump. Either way the answers are
/// offline's without stamps, and the daemon's log says where it jumped and where it took a step
/// for poses missing (before 2026-12-02, untold); the answers after that step carry the
/// `poses_missing` warning (before, no bit said it).
#[test]
fn a_paused_odometry_is_judged_by_its_stamps() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("paused");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    // The town's first corner is 720 m (poses) into the drive.
    for (paused_at, corner) in [(600, false), (710, true)] {
        let poses: Vec<Pose3> = odometry[..paused_at]
            .iter()
            .chain(&odometry[paused_at + 30..paused_at + 300])
            .copied()
            .collect();
        let stamps_s: Vec<f64> = (0..poses.len())
            .map(|i| 1000.0 + i as f64 * 0.1 + if i < paused_at { 0.0 } else { 3.0 })
            .collect();
        let stamps: Vec<i64> = stamps_s.iter().map(|t| (t * 1e9).round() as i64).collect();
        let answered = |stamps: &[i64]| {
            let mut conn = connect(&setup, &name);
            let r = replay(
                &mut conn,
                &name,
                &poses,
                stamps,
                Rate::Max(16),
                Duration::from_secs(10),
                Duration::from_secs(10),
            )
            .unwrap();
            let jumps = seqs_where(&r.answers, |a| a.status() == Some(StatusCode::OdometryJump));
            // The answers that carry the warning: every one after the step it was raised by.
            let missing = seqs_where(&r.answers, |a| {
                a.warnings & Warning::PosesMissing.bit() != 0
            });
            (poses_of(&r.answers), jumps, missing)
        };
        let (stamped, jumps, missing) = answered(&stamps);
        assert!(jumps.is_empty(), "{jumps:?}");
        assert!(missing.is_empty(), "{missing:?}");
        assert!(stamped == offline_stamped(&setup, &name, &poses, Some(&stamps_s)));
        let (unstamped, jumps, missing) = answered(&[]);
        assert!(unstamped == offline(&setup, &name, &poses));
        let seq = paused_at as u64 + 1;
        if corner {
            assert_eq!(jumps, [seq], "the pose after the pause");
            assert!(missing.is_empty(), "{missing:?}");
            assert!(unstamped != stamped);
        } else {
            assert!(jumps.is_empty(), "{jumps:?}");
            let after: Vec<u64> = (seq + 1..=poses.len() as u64).collect();
            assert_eq!(missing, after, "raised by the pose after the pause");
        }
    }
    let log = log_once_it_says(&daemon, "the odometry jumped");
    assert_eq!(log.matches("the odometry jumped").count(), 1, "{log}");
    // The straight's pause, unstamped.
    let missing = the_line_saying(&log, "a step of the odometry was taken for poses missing");
    assert!(missing.contains("seq=601"), "{missing}");
    assert!(daemon.stop().unwrap(), "clean exit");
}

/// Always runs: an odometry that glitches on every other pose (the town's drive, each odd pose
/// from 50 on published 300 m to the side, the next on it again) is answered as offline, its
/// glitches jumps; the daemon's log tells the first jump and, where the session ends, how many
/// more there were, instead of a line for each (before: one WARN per jump, 50 a second for such
/// an odometry at 100 Hz).
#[test]
fn an_odometry_that_keeps_jumping_is_told_once_and_counted() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("glitch");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let poses = glitching(&odometry[..400]);
    let (answers, conn) = replay_session(&setup, &name, &poses, &[], Rate::Max(16));
    assert!(poses_of(&answers) == offline(&setup, &name, &poses));
    let jumps = answers
        .iter()
        .filter(|a| a.status() == Some(StatusCode::OdometryJump))
        .count();
    assert!(jumps > 100, "{jumps} jumps");
    closed(conn, &daemon, 0);
    let log = log_once_it_says(&daemon, "more times since the last jump told");
    assert_eq!(log.matches("the odometry jumped:").count(), 1, "{log}");
    let untold = the_line_saying(&log, "more times since the last jump told");
    assert!(
        untold.contains(&format!("jumps={}", jumps - 1)),
        "{jumps} jumps: {log}"
    );
    assert!(daemon.stop().unwrap(), "clean exit");
}

/// Always runs: an odometry that loses track at speed (the town's drive at 10 m/s, then the
/// same poses each given ten times: a standstill no car reaches in a step) is answered as offline,
/// and the daemon's log says once where its speed changed faster than a car's can. The drive
/// without the stall says nothing of it.
#[test]
fn an_odometry_that_stalls_is_told_in_the_log() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("stall");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let stalled: Vec<Pose3> = odometry[..300]
        .iter()
        .chain((0..200).map(|i| &odometry[300 + i / 10]))
        .copied()
        .collect();
    for (k, (poses, told)) in [(&odometry[..500], 0), (&stalled[..], 1)]
        .into_iter()
        .enumerate()
    {
        let (session, raised) = replayed_as_offline(&setup, &name, poses);
        closed(session, &daemon, k);
        let log = daemon.log();
        assert_eq!(speed_change_lines(&log).len(), told, "{log}");
        assert_eq!(
            raised,
            [Warning::LostTrack][..told],
            "raised in the answers"
        );
    }
    // Pose 300 goes out as sequence number 301.
    let log = daemon.log();
    let seq: u64 = speed_change_lines(&log)
        .first()
        .and_then(|l| seq_of(l))
        .unwrap_or_else(|| panic!("{log}"));
    assert!((298..=304).contains(&seq), "{seq}: {log}");
    assert!(daemon.stop().unwrap(), "clean exit");
}

/// The daemon's WARN lines in `log` that a session's speed changed faster than a car's can.
fn speed_change_lines(log: &str) -> Vec<&str> {
    log.lines()
        .filter(|l| l.contains("speed changed faster than a car's can"))
        .collect()
}

/// The sequence number a log line names (`seq=`).
fn seq_of(line: &str) -> Option<u64> {
    let rest = line.split("seq=").nth(1)?;
    rest.split(|c: char| !c.is_ascii_digit())
        .next()?
        .parse()
        .ok()
}

/// A session of `source` that has replayed `poses` (unstamped, 16 in flight), their answers
/// checked equal to offline correction's: the connection, and the warnings its last answer
/// carries (what the session's poses raised before it).
fn replayed_as_offline(setup: &Setup, source: &str, poses: &[Pose3]) -> (Connection, Vec<Warning>) {
    let (answers, conn) = replay_session(setup, source, poses, &[], Rate::Max(16));
    assert!(poses_of(&answers) == offline(setup, source, poses));
    let raised = answers.last().map(|a| a.warnings().collect());
    (conn, raised.unwrap_or_default())
}

/// `poses` (in `setup`'s axis convention, metres) with their planar positions in centimetres.
fn in_centimetres(setup: &Setup, poses: &[Pose3]) -> Vec<Pose3> {
    poses
        .iter()
        .map(|p| {
            let mut planar = setup.convention.to_planar(p);
            planar.translation *= 100.0;
            setup.convention.from_planar(&planar)
        })
        .collect()
}

/// `poses` (in `setup`'s axis convention) moved in the plane by `by_m` (x, y in metres).
fn moved(setup: &Setup, poses: &[Pose3], by_m: [f64; 2]) -> Vec<Pose3> {
    poses
        .iter()
        .map(|p| {
            let mut planar = setup.convention.to_planar(p);
            planar.translation[0] += by_m[0];
            planar.translation[1] += by_m[1];
            setup.convention.from_planar(&planar)
        })
        .collect()
}

/// Always runs: a session that ends in a stall (the town's drive at 10 m/s, then its last pose
/// five times more) is told of it when its client closes it: after 300 poses, and after 45,
/// before its stamps could tell the rate. While it ran, nothing was told.
#[test]
fn a_stall_where_the_session_ends_is_told_when_it_ends() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("endstall");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let told = |log: &str| -> Vec<u64> {
        speed_change_lines(log)
            .into_iter()
            .filter_map(seq_of)
            .collect()
    };
    for (i, moving) in [300, 45].into_iter().enumerate() {
        let poses: Vec<Pose3> = odometry[..moving]
            .iter()
            .chain([&odometry[moving - 1]; 5])
            .copied()
            .collect();
        let (conn, raised) = replayed_as_offline(&setup, &name, &poses);
        assert_eq!(told(&daemon.log()).len(), i, "{}", daemon.log());
        assert_eq!(raised, [], "nothing raised while the session ran");
        closed(conn, &daemon, i);
        // Pose `moving` goes out as sequence number `moving + 1`; the change lies between the
        // half second before it and the one after.
        let seq = told(&daemon.log())[i];
        let at = moving as u64 + 1;
        assert!((at - 6..=at + 1).contains(&seq), "{seq} for {at}");
    }
    assert!(daemon.stop().unwrap(), "clean exit");
}

/// Always runs: a session set up wrongly is told in the daemon's log, as `correct` tells a file:
/// the town's drive in a camera's axes sent to a source set for `flu` (it moves vertically: told
/// once it has gone 60 m, naming the frame that fits; in the plane it stands still, so no
/// alignment is tried), and the drive 5 km beside the map (no correction accepted in the first
/// 100 attempts, told once, while it runs; a session that ends before 100 attempts is told when
/// it ends). The drive as it is tells neither. The answers are offline's throughout. Last, the
/// drive with its rotations made from quaternions read scalar first (`qw qx qy qz`): upside down,
/// told once its first 300 m are judged, naming the quaternion order; and the drive beside the
/// map with each pose sent twice, told once. What is told while a session runs is raised in its
/// later answers (`CorrectedPose::warnings`).
#[test]
fn a_session_set_up_wrongly_is_told_in_the_log() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("setup");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let drive = &odometry[..400];
    let camera: Vec<Pose3> = drive
        .iter()
        .map(|p| AxisConvention::KittiCamera.from_planar(&setup.convention.to_planar(p)))
        .collect();
    let far = moved(&setup, drive, [5000.0, 5000.0]);
    // Each pose sent twice: the second tries no alignment, so the count of attempts stays at
    // 100 over two poses (until 2026-12-02 the warning was told for both).
    let far_twice: Vec<Pose3> = far.iter().flat_map(|&p| [p, p]).collect();
    let scalar_first: Vec<Pose3> = drive
        .iter()
        .map(|p| {
            let [x, y, z, w] = quaternion_from_rotation(&p.rotation);
            Pose3 {
                rotation: rotation_from_quaternion([w, x, y, z]),
                ..*p
            }
        })
        .collect();
    let count = |what: &str| daemon.log().matches(what).count();
    let axes = "the poses probably use another axis convention; try --frame kitti-camera";
    let refused = "no correction was accepted in";
    let tilted = "were these written qw qx qy qz?";
    // The warnings each session's last answer carries: a session of 150 poses tries fewer than
    // 100 alignments, and is told when it ends.
    let (axes_raised, refused_raised) = (&[Warning::Axes][..], &[Warning::Refusals][..]);
    let runs = [
        (drive, 0, 0, 0, &[][..]),
        (&camera[..], 1, 0, 0, axes_raised),
        (&far[..], 1, 1, 0, refused_raised),
        (&far[..150], 1, 2, 0, &[]),
        (&scalar_first[..], 1, 2, 1, axes_raised),
        (&far_twice[..], 1, 3, 1, refused_raised),
    ];
    for (i, (poses, told_axes, told_refused, told_tilted, raised)) in runs.into_iter().enumerate() {
        let (conn, raised_before_the_last) = replayed_as_offline(&setup, &name, poses);
        closed(conn, &daemon, i);
        assert_eq!(raised_before_the_last, raised, "{i}");
        assert_eq!(count(axes), told_axes, "{}", daemon.log());
        assert_eq!(count(refused), told_refused, "{}", daemon.log());
        assert_eq!(count(tilted), told_tilted, "{}", daemon.log());
    }
    assert_eq!(
        count("no correction was accepted in 100 attempts over "),
        2,
        "{}",
        daemon.log()
    );
    assert!(daemon.stop().unwrap(), "clean exit");
}

/// Always runs: a session whose positions are in centimetres (the town's drive, about 10 m/s
/// read as 1000) is told once in the daemon's log, by its pace, naming the units, as `correct` tells a
/// file; the changes of speed its corners make, 100 times steeper than a car's, are not told as
/// an odometry that lost track. The answers are offline's. The drive in metres tells neither.
#[test]
fn a_session_in_centimetres_is_told_its_pace_in_the_log() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("pace");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let metres = &odometry[..400];
    let centimetres = in_centimetres(&setup, metres);
    let pace = "are its positions in metres";
    for (i, (poses, told)) in [(metres, 0), (&centimetres[..], 1)].into_iter().enumerate() {
        let (conn, raised) = replayed_as_offline(&setup, &name, poses);
        closed(conn, &daemon, i);
        assert_eq!(raised, [Warning::Pace][..told], "raised in the answers");
        let log = daemon.log();
        assert_eq!(log.matches(pace).count(), told, "{log}");
        assert_eq!(speed_change_lines(&log), Vec::<&str>::new(), "{log}");
    }
    // The town's odometry drives about 1 m a pose, with its noise.
    let log = daemon.log();
    let speed: f64 = log
        .split("the odometry moves at ")
        .nth(1)
        .and_then(|rest| rest.split(' ').next()?.parse().ok())
        .unwrap_or_else(|| panic!("{log}"));
    assert!((950.0..1050.0).contains(&speed), "{log}");
    assert!(daemon.stop().unwrap(), "clean exit");
}

/// Always runs: a session stamped in microseconds sent as the wire's nanoseconds (the town's 10
/// Hz read as 10 kHz), and one in milliseconds (10 MHz), is asked about its stamps' unit, once,
/// and raises `rate`; its speed is judged at the rate its source is set for, so it is not told it
/// moves faster than any vehicle (until 2026-12-02: "set odometry_rate_hz = 10000" and a pace of
/// 10 000 m/s for microseconds; nothing at all for milliseconds, whose stamps, less than 10 us
/// apart, were taken for counters). The answers are offline's with the same stamps.
#[test]
fn a_session_stamped_in_microseconds_is_asked_about_them() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("micro");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let poses = &odometry[..400];
    for (k, (period, apart)) in [(100_000, "100 us"), (100, "100 ns")]
        .into_iter()
        .enumerate()
    {
        let stamps_ns: Vec<i64> = (0..400).map(|i| 1_000_000 + period * i).collect();
        let (answers, conn) = replay_session(&setup, &name, poses, &stamps_ns, Rate::Max(16));
        let stamps_s: Vec<f64> = stamps_ns.iter().map(|&ns| ns as f64 * 1e-9).collect();
        assert!(poses_of(&answers) == offline_stamped(&setup, &name, poses, Some(&stamps_s)));
        closed(conn, &daemon, k);
        let raised: Vec<Warning> = answers.last().unwrap().warnings().collect();
        assert_eq!(raised, [Warning::Rate], "{apart}");
        let log = daemon.log();
        let asked = format!("stamps are {apart} apart");
        assert_eq!(log.matches(&asked).count(), 1, "{log}");
        assert_eq!(
            log.matches("Microseconds sent as nanoseconds").count(),
            k + 1,
            "{log}"
        );
        assert!(!log.contains("the odometry moves at"), "{log}");
        assert_eq!(speed_change_lines(&log), Vec::<&str>::new(), "{log}");
    }
    assert!(daemon.stop().unwrap(), "clean exit");
}

/// Always runs: `lanealign replay` warns of what `lanealign correct` would, from the daemon's
/// answers: a drive 5 km beside the town's map (no correction accepted: a wrong anchor or
/// frame), a drive whose odometry jumps 300 m at pose 200 (told with its sequence number,
/// 201), a drive in centimetres (what the daemon raised in its answers: its pace, judged at the
/// 64th pose and carried from the next) and a drive that paused on a straight without stamps
/// (raised: a step taken for poses missing, at seq 201; before 2026-12-02 `correct` warned of it
/// and `replay` did not). Each raised warning names the first answer that carries it. The
/// town's drive as it is warns of none.
#[test]
fn replay_warns_of_a_setup_gone_wrong_and_of_jumps() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("replaywarn");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let drive = &odometry[..400];
    let far = moved(&setup, drive, [5000.0, 5000.0]);
    // Sideways: a step ahead along the drive would be poses missing from the file.
    let jumped: Vec<Pose3> = drive[..200]
        .iter()
        .copied()
        .chain(moved(&setup, &drive[200..], [0.0, 300.0]))
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let (input, output) = (dir.path().join("in.txt"), dir.path().join("out.txt"));
    let warned = |poses: &[Pose3]| -> Vec<String> {
        write_kitti(&input, poses);
        let out = Command::new(env!("CARGO_BIN_EXE_lanealign"))
            .args(["replay", "--source", &name, "--namespace", &setup.namespace])
            .arg(&input)
            .arg("-o")
            .arg(&output)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(out.status.success(), "{stderr}");
        let lines = stderr.lines().filter(|l| l.starts_with("WARN "));
        lines.map(str::to_string).collect()
    };
    assert_eq!(warned(drive), Vec::<String>::new());
    let far = warned(&far);
    assert_eq!(far.len(), 1, "{far:?}");
    assert!(
        far[0].contains("no correction was accepted in")
            && far[0].contains("attempts over 400 poses")
            && far[0].contains("anchor and frame in lanealignd's configuration"),
        "{far:?}"
    );
    let jumped = warned(&jumped);
    assert_eq!(jumped.len(), 1, "{jumped:?}");
    assert!(
        jumped[0].contains("the odometry jumped at 1 pose (sequence number 201)"),
        "{jumped:?}"
    );
    // What the daemon raised in the answers beyond that: the drive in centimetres moves
    // faster than any vehicle (and its poses, 1 m apart read as 100 m, never fill a window).
    let paced = warned(&in_centimetres(&setup, drive));
    assert_eq!(paced.len(), 2, "{paced:?}");
    assert!(
        paced[0].contains("no alignment was tried in 400 poses"),
        "{paced:?}"
    );
    assert!(
        paced[1].contains(
            "the daemon raised in this session's answers: pace from sequence number 65 on (its \
             poses move faster than any vehicle: are its positions in metres"
        ),
        "{paced:?}"
    );
    let paused: Vec<Pose3> = drive[..200].iter().chain(&drive[230..]).copied().collect();
    let paused = warned(&paused);
    assert_eq!(paused.len(), 1, "{paused:?}");
    assert!(
        paused[0].contains(
            "the daemon raised in this session's answers: poses_missing from sequence number \
             202 on (a step of its odometry was longer than the vehicle drives in one period"
        ),
        "{paused:?}"
    );
    assert!(daemon.stop().unwrap(), "clean exit");
}

/// Always runs: a source at 2 Hz whose corrector is set for the town's 10 Hz has its speed
/// judged at the rate its stamps say, as `correct` judges a file. Its braking and speeding up at
/// 4 m/s^2 (read at 10 Hz, 25 times steeper) tells nothing; the same drive stalling at 12 m/s
/// at pose 3, before the stamps have told the rate (it stands for 3 s, then goes on at 4 m/s),
/// is told there once. The answers are offline's with the stamps, and the rate warning is logged
/// for both drives.
#[test]
fn a_slower_source_is_judged_at_the_rate_of_its_stamps() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("slower");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    // The town's poses lie 1 m apart, its first corner 480 m into the drive: a stride of 6 poses
    // every 0.5 s is 12 m/s, one less each step brakes at 2 m/s per step (4 m/s^2), down to
    // 4 m/s and back, every 15 s (once before the stamps have told the rate, twice after).
    let strides: Vec<usize> = (0..100usize)
        .map(|k| match k % 30 {
            k @ 5..9 => 6 - (k - 4),
            9..15 => 2,
            k @ 15..19 => 2 + (k - 14),
            _ => 6,
        })
        .collect();
    let at = |strides: &[usize]| -> Vec<Pose3> {
        strides
            .iter()
            .scan(0, |index, &stride| {
                *index += stride;
                Some(odometry[*index])
            })
            .collect()
    };
    let braking = at(&strides);
    let mut stalling = strides.clone();
    stalling[3..9].fill(0);
    let stalled = at(&stalling);
    assert!(
        !lanealign_core::plausibility::speed_changes(&planar(&setup, &braking), 10.0).is_empty(),
        "read at 10 Hz, the braking would be told"
    );
    let stamps_s: Vec<f64> = (0..100).map(|i| 1000.0 + 0.5 * i as f64).collect();
    let stamps: Vec<i64> = stamps_s.iter().map(|t| (t * 1e9).round() as i64).collect();
    for (k, (poses, told)) in [(&braking, 0), (&stalled, 1)].into_iter().enumerate() {
        let (answers, session) = replay_session(&setup, &name, poses, &stamps, Rate::Max(16));
        assert!(poses_of(&answers) == offline_stamped(&setup, &name, poses, Some(&stamps_s)));
        // What a session told is in the log once its end is: the worker logs both, in order.
        // (Read right after the last answer, a loaded machine's log had not caught up.)
        closed(session, &daemon, k);
        let log = daemon.log();
        assert_eq!(speed_change_lines(&log).len(), told, "{log}");
    }
    let log = daemon.log();
    assert_eq!(
        log.matches("the poses come at about 2.0 Hz").count(),
        2,
        "{log}"
    );
    let line = *speed_change_lines(&log)
        .first()
        .unwrap_or_else(|| panic!("{log}"));
    assert!(line.contains("rate_hz=2"), "{line}");
    // Pose 3 goes out as sequence number 4.
    let seq: u64 = seq_of(line).unwrap_or_else(|| panic!("{line}"));
    assert!((2..=6).contains(&seq), "{seq}: {line}");
    assert!(daemon.stop().unwrap(), "clean exit");
}

/// The planar positions (metres) of `poses`, given in `setup`'s axis convention.
fn planar(setup: &Setup, poses: &[Pose3]) -> Vec<[f64; 2]> {
    poses
        .iter()
        .map(|p| setup.convention.to_planar(p).planar_position())
        .collect()
}

/// Always runs: while answers flow, a client does not look for its daemon (listing the
/// namespace's nodes is file-system work that held up the answers arriving meanwhile: the
/// round trip's p99 at 8 sources x 1000 Hz was 1.9-2.1 ms with a look every 100 ms, 1.1-1.2 ms
/// without, docs/performance.md). Two seconds at 500 Hz: a look when the connection is made,
/// perhaps one while waiting for the daemon, one at the first answer (20 with a look every
/// 100 ms).
#[test]
fn answers_that_flow_need_no_looking_for_the_daemon() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("flow");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let poses = &odometry[..1000];
    let mut conn = connect(&setup, &name);
    wait_for_daemon(&mut conn);
    let r = replay(
        &mut conn,
        &name,
        poses,
        &[],
        Rate::Hz(500.0),
        Duration::from_secs(10),
        Duration::from_secs(10),
    )
    .unwrap();
    assert!(poses_of(&r.answers) == offline(&setup, &name, poses));
    assert!(r.events.liveness_checks <= 3, "{:?}", r.events);
    assert!(daemon.stop().unwrap(), "clean exit");
}

/// Always runs: a wait longer than any instant (`Duration::MAX`, `--wait-for-daemon 1e19`) is a
/// wait without end, not a panic: `Instant::now() + timeout` overflowed in the client's `recv`
/// and `close`, the Python package's `recv` and `replay`'s wait for its daemon.
#[test]
fn a_wait_without_end_returns_what_arrives() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("forever");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let mut conn = connect(&setup, &name);
    wait_for_daemon(&mut conn);
    let seq = conn.publish(0, &odometry[0].to_row_major()).unwrap();
    let answer = conn.recv(Duration::MAX).unwrap().expect("an answer");
    assert_eq!(answer.seq, seq);
    conn.publish(1, &odometry[1].to_row_major()).unwrap();
    let closed = conn.close(Duration::MAX).unwrap();
    assert_eq!(closed.answers.len(), 1);
    assert!(closed.unanswered.is_empty() && closed.daemon_told);
    let dir = tempfile::tempdir().unwrap();
    let (input, output) = (dir.path().join("in.txt"), dir.path().join("out.txt"));
    write_kitti(&input, &odometry[..20]);
    let out = Command::new(env!("CARGO_BIN_EXE_lanealign"))
        .args(["replay", "--source", &name, "--namespace", &setup.namespace])
        .args(["--wait-for-daemon", "1e19"])
        .arg(&input)
        .arg("-o")
        .arg(&output)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(
        std::fs::read_to_string(&output).unwrap().lines().count(),
        20
    );
    assert!(daemon.stop().unwrap(), "clean exit");
}

/// Always runs: one connection, made on this thread and shared behind a lock by two others:
/// one publishes a synthetic-town drive, a pose every 2 ms, the other takes answers under the
/// lock and waits for them outside it ([`Connection::waiter`]). Every pose is answered once,
/// equal to offline correction bit for bit, and no publish waits for the receiver's waits (a
/// receiver waiting under the lock would hold it up to 100 ms while nothing is in flight).
#[test]
fn one_connection_publishes_on_one_thread_and_receives_on_another() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("threads");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(2, 42);
    let poses = &odometry[..600];
    let mut conn = connect(&setup, &name);
    wait_for_daemon(&mut conn);
    let shared = Mutex::new(conn);
    let (answers, longest_lock_wait) = std::thread::scope(|s| {
        let publisher = s.spawn(|| {
            let mut longest = Duration::ZERO;
            for (k, pose) in poses.iter().enumerate() {
                let asked = Instant::now();
                let mut conn = shared.lock().unwrap();
                longest = longest.max(asked.elapsed());
                conn.publish(k as i64, &pose.to_row_major()).unwrap();
                drop(conn);
                std::thread::sleep(Duration::from_millis(2));
            }
            longest
        });
        let receiver = s.spawn(|| {
            let mut answers = Vec::new();
            let until = Instant::now() + Duration::from_secs(30);
            while answers.len() < poses.len() && Instant::now() < until {
                let (answer, waiter) = {
                    let mut conn = shared.lock().unwrap();
                    (conn.poll().unwrap(), conn.waiter())
                };
                match answer {
                    Some(answer) => answers.push(answer),
                    None => waiter.wait(Duration::from_millis(100)).unwrap(),
                }
            }
            answers
        });
        (receiver.join().unwrap(), publisher.join().unwrap())
    });
    let seqs: Vec<u64> = answers.iter().map(|a| a.seq).collect();
    assert_eq!(seqs, (1..=poses.len() as u64).collect::<Vec<_>>());
    assert!(poses_of(&answers) == offline(&setup, &name, poses));
    assert!(
        longest_lock_wait < Duration::from_millis(50),
        "a publish waited {longest_lock_wait:?} for the lock"
    );
    let closed = shared
        .into_inner()
        .unwrap()
        .close(Duration::from_secs(5))
        .unwrap();
    assert!(closed.daemon_told && closed.unanswered.is_empty());
    assert!(daemon.stop().unwrap(), "clean exit");
}

/// Always runs: workers and clients that poll (busy-spin, and spin-then-block with pauses
/// longer than its budget, so that it blocks too) answer every pose once, equal to offline
/// correction bit for bit.
#[test]
fn spinning_workers_and_clients_answer_every_pose_as_offline() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let (busy, spin) = (unique("busy"), unique("spin"));
    let setup = town_setup(&[&busy, &spin]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(2, 42);
    let poses = &odometry[..800];
    for name in [&busy, &spin] {
        let mut conn = connect(&setup, name);
        conn.set_wait_strategy(wait_of(name));
        wait_for_daemon(&mut conn);
        let r = replay(
            &mut conn,
            name,
            poses,
            &[],
            Rate::Hz(1000.0),
            Duration::from_secs(10),
            Duration::from_secs(10),
        )
        .unwrap();
        let seqs: Vec<u64> = r.answers.iter().map(|x| x.seq).collect();
        assert_eq!(seqs, (1..=poses.len() as u64).collect::<Vec<_>>());
        assert!(
            poses_of(&r.answers) == offline(&setup, name, poses),
            "{name}"
        );
    }
    let log = daemon.log();
    assert!(daemon.stop().unwrap(), "clean exit");
    for wait in ["busy-spin", "spin-then-block:200"] {
        assert!(log.contains(&format!("wait={wait}")), "{log}");
    }
}

#[test]
fn two_kitti_sources_at_once_match_offline_bit_for_bit() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some(data) = shared_data() else { return };
    let (a, b) = (unique("lidar07"), unique("smooth08"));
    let setup = kitti_setup(&data, &[(&a, "07"), (&b, "08")]);
    let daemon = start(&setup);
    let (poses_a, poses_b) = (lidar_run(&data, "07"), lidar_run(&data, "08"));
    let (got_a, got_b) = replay_two(&setup, (&a, &poses_a), (&b, &poses_b), Rate::Max(32));
    assert!(daemon.stop().unwrap(), "clean exit");
    assert!(got_a == offline(&setup, &a, &poses_a), "{a}: bit for bit");
    assert!(got_b == offline(&setup, &b, &poses_b), "{b}: bit for bit");
}

/// KITTI 07 and 08 through a daemon serving a grid of 200 m cells, flooded as `replay` does
/// by default: each session loads the cells around it on the daemon's loader thread as it
/// drives, and its answers equal offline correction on the whole tile bit for bit; no query
/// reached past its loaded cells.
#[test]
fn kitti_on_a_grid_matches_the_whole_tile_bit_for_bit() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let Some(data) = shared_data() else { return };
    let (a, b) = (unique("lidar07"), unique("lidar08"));
    let setup = kitti_setup_on(&data, &[(&a, "07"), (&b, "08")], Some(200.0));
    let daemon = start(&setup);
    let (poses_a, poses_b) = (lidar_run(&data, "07"), lidar_run(&data, "08"));
    let (got_a, got_b) = replay_two(&setup, (&a, &poses_a), (&b, &poses_b), Rate::Max(32));
    // One more metrics interval, so that the last poses are reported.
    std::thread::sleep(Duration::from_millis(1200));
    let log = daemon.log();
    assert!(daemon.stop().unwrap(), "clean exit");
    assert!(got_a == offline(&setup, &a, &poses_a), "{a}: bit for bit");
    assert!(got_b == offline(&setup, &b, &poses_b), "{b}: bit for bit");
    let field = |line: &str, key: &str| -> Option<u64> {
        let at = line.find(&format!(" {key}="))? + key.len() + 2;
        line[at..]
            .split(|c: char| !c.is_ascii_digit())
            .next()?
            .parse()
            .ok()
    };
    let latency: Vec<&str> = log.lines().filter(|l| l.contains(" latency")).collect();
    let swaps: u64 = latency.iter().filter_map(|l| field(l, "map_swaps")).sum();
    let uncovered: u64 = latency
        .iter()
        .filter_map(|l| field(l, "uncovered_queries"))
        .sum();
    assert!(
        swaps > 10,
        "sessions moved to new maps as they drove: {swaps}\n{log}"
    );
    assert_eq!(uncovered, 0, "{log}");
    assert!(log.contains("resident_cells="), "the loader reports: {log}");
    assert!(log.contains(" map_waits="), "waits are reported: {log}");
}

/// A flagged or gap answer has no correction, covariance, anchor or scale (docs/wire.md).
fn assert_all_nan(a: &CorrectedPose) {
    let numbers = [
        &a.map_from_odom[..],
        &a.covariance[..],
        &[a.anchor_yaw, a.odometry_scale, a.odometry_scale_sd][..],
    ]
    .concat();
    assert!(numbers.iter().all(|v| v.is_nan()), "{a:?}");
}

/// Always runs: through a raw wire client, the protocol of sequence numbers: non-finite poses
/// use up their number and change nothing, a used number with another pose is flagged, a used
/// number with the same pose gets the same answer again, a number beyond the next is a gap;
/// poses for an unconfigured source are refused and counted.
#[test]
fn bad_input_is_flagged_and_changes_nothing() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("bad");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let good_poses = &odometry[..400];
    let raw = RawClient::new(&setup, &name);
    let mut good = Vec::new();
    let mut seq = 0;
    for (i, p) in good_poses.iter().enumerate() {
        seq += 1;
        good.push(raw.send(seq, p.to_row_major()));
        if i == 200 {
            let mut nan = p.to_row_major();
            nan[3] = f64::NAN;
            seq += 1;
            let refused = raw.send(seq, nan);
            assert_eq!(refused.status(), Some(StatusCode::InvalidInput));
            assert_all_nan(&refused);
            // Sent again (as a client does after a daemon restart), it is the same pose and
            // gets its answer again, not `duplicate_seq`.
            let again = raw.send(seq, nan);
            assert_eq!(again.status(), Some(StatusCode::InvalidInput));
            assert_eq!(again.seq, seq);
            let mut inf = p.to_row_major();
            inf[11] = f64::INFINITY;
            seq += 1;
            assert_eq!(raw.send(seq, inf).status(), Some(StatusCode::InvalidInput));
            let other = odometry[500].to_row_major();
            let duplicate = raw.send(seq, other);
            assert_eq!(duplicate.status(), Some(StatusCode::DuplicateSeq));
            assert_all_nan(&duplicate);
            assert_eq!(
                raw.send(seq - 40, other).status(),
                Some(StatusCode::OutOfOrderSeq)
            );
            let ahead = raw.send(seq + 5, other);
            assert_eq!(ahead.status(), Some(StatusCode::Gap));
            assert_all_nan(&ahead);
            assert_eq!(ahead.expected_seq, seq + 1);
            // The same pose under a used number: the same answer again.
            let again = raw.send(seq - 3, good_poses[i - 1].to_row_major());
            assert_eq!(again.pose, good[i - 1].pose);
            assert_eq!(again.status, good[i - 1].status);
        }
    }
    // Poses for a source the daemon does not serve are refused and counted.
    let mut stranger = connect(&setup, &unique("nobody"));
    stranger.publish(0, &good_poses[0].to_row_major()).unwrap();
    let until = Instant::now() + Duration::from_secs(5);
    while !daemon.log().contains("refused_sources=1") && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(
        daemon.log().contains("not configured are refused")
            && daemon.log().contains("refused_sources=1"),
        "{}",
        daemon.log()
    );
    assert!(stranger.recv(Duration::from_millis(200)).unwrap().is_none());
    // The metrics split the corrector's time and count what the protocol refused.
    let until = Instant::now() + Duration::from_secs(5);
    while !daemon.log().contains("bookkeeping_p99_us") && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(50));
    }
    let log = daemon.log();
    for key in [
        "matching_p99_us",
        "icp_p99_us",
        "bookkeeping_p99_us",
        "handling_p99_us",
        "e2e_p999_us",
        "daemon_p999_us",
        "gaps=1",
        "resent=2",
        "sessions=1",
    ] {
        assert!(log.contains(key), "{key} in {log}");
    }
    drop((raw, stranger));
    assert!(daemon.stop().unwrap());
    // The flagged inputs changed nothing: the good answers equal offline correction of the
    // good poses alone.
    assert!(offline(&setup, &name, good_poses) == poses_of(&good));
}

/// Always runs: a second daemon in a namespace refuses to start, naming the first.
#[test]
fn one_daemon_per_namespace() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let setup = town_setup(&[&unique("one")]);
    let first = start(&setup);
    let second = DaemonProcess::start(&setup.config, &setup.dir.path().join("second.log")).unwrap();
    let log_path = setup.dir.path().join("second.log");
    let status = second.wait().unwrap();
    let log = std::fs::read_to_string(log_path).unwrap();
    assert!(!status.success(), "{log}");
    assert!(
        log.contains("another lanealignd serves namespace")
            && log.contains(&format!("pid {}", first.id())),
        "{log}"
    );
    // Another namespace on the same machine is another deployment: it starts.
    let other = town_setup(&[&unique("other")]);
    let neighbour = start(&other);
    assert!(neighbour.stop().unwrap() && first.stop().unwrap());
}

/// Always runs: a daemon of another lanealign version (injected as what a client sees of one:
/// a node of the namespace with an older daemon's name) is named at once, not waited for. A
/// client cannot connect beside one from before wire versions were named; a daemon of this
/// version does not start beside it; a daemon of an older numbered wire that replaces this
/// version's under a running connection makes `recv` say so; and once a daemon of this version
/// is back, the pose in flight is answered.
#[test]
fn a_daemon_of_another_version_is_named_not_waited_for() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("version");
    let setup = town_setup(&[&name]);
    let ns = namespace(&setup);
    let older = ns.named_node::<Ipc>(DAEMON_NODE).unwrap();
    let refused = Connection::connect_in(&ns, &name.parse().unwrap(), new_session_id())
        .err()
        .expect("no connection beside a daemon of another version");
    let text = refused.to_string();
    assert!(
        text.contains(&format!("pid {}", std::process::id()))
            && text.contains("a wire from before versions were named")
            && text.contains(&format!("this build wire {WIRE_VERSION}")),
        "{text}"
    );
    let log_path = setup.dir.path().join("beside.log");
    let beside = DaemonProcess::start(&setup.config, &log_path).unwrap();
    let status = beside.wait().unwrap();
    let log = std::fs::read_to_string(&log_path).unwrap();
    assert!(
        !status.success()
            && log.contains("another lanealignd serves namespace")
            && log.contains(&format!("this build wire {WIRE_VERSION}")),
        "{log}"
    );
    drop(older);

    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let mut conn = connect(&setup, &name);
    wait_for_daemon(&mut conn);
    answer_of(&mut conn, &odometry[0]);
    daemon.kill().unwrap();
    let numbered = ns
        .named_node::<Ipc>(&format!("{DAEMON_NODE} wire 1"))
        .unwrap();
    conn.publish(0, &odometry[1].to_row_major()).unwrap();
    let error = conn
        .recv(Duration::from_secs(5))
        .expect_err("recv names the daemon of another version");
    assert!(error.to_string().contains("speaks wire 1"), "{error}");
    drop(numbered);
    let daemon = start(&setup);
    let answer = conn
        .recv(Duration::from_secs(5))
        .unwrap()
        .expect("the pose in flight answered by this version's daemon");
    assert_eq!(answer.seq, 2);
    assert!(conn.close(Duration::from_secs(5)).unwrap().daemon_told);
    assert!(daemon.stop().unwrap());
}

/// Always runs: with too few file descriptors for 100 sources, a worker cannot open its ports:
/// the daemon stops with a non-zero exit naming the source and the cause, instead of running
/// with sources missing.
#[test]
fn a_source_that_cannot_start_stops_the_daemon() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let names: Vec<String> = (0..100).map(|k| format!("many-{k}")).collect();
    let refs: Vec<&str> = names.iter().map(String::as_str).collect();
    let setup = town_setup(&refs);
    let out = Command::new("bash")
        .arg("-c")
        .arg(format!(
            "ulimit -n 64; exec {} --config {}",
            daemon_binary().unwrap().display(),
            setup.config.display()
        ))
        .stdout(Stdio::null())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(err.contains("error: source many-"), "{err}");
    assert!(err.contains("caused by"), "{err}");
}

/// The kernel's CPU wake-up latency (us) before `test` has a daemon ask for 0 us, or `None` (and
/// `test` said skipped) where it cannot tell: without write access to the device, once `refused`
/// has asserted how the daemon refuses the request there; or where another process holds 0 us
/// already.
fn latency_before(test: &str, refused: impl FnOnce()) -> Option<i32> {
    if cpu_latency::check(std::path::Path::new(cpu_latency::DEVICE)).is_err() {
        refused();
        skipped(
            test,
            &format!("needs write access to {}", cpu_latency::DEVICE),
        );
        return None;
    }
    let before = kernel_latency();
    if before == 0 {
        skipped(test, "another process holds 0 us already");
        return None;
    }
    Some(before)
}

/// The CPU wake-up latency the kernel keeps to now (us).
fn kernel_latency() -> i32 {
    cpu_latency::current(std::path::Path::new(cpu_latency::DEVICE)).unwrap()
}

/// A configuration's `cpu_dma_latency_us` is asked of the kernel while the daemon runs: in
/// effect as soon as the daemon is ready, and ended with it, stopped or killed (the kernel ends
/// the request with the process); `check` passes and asks nothing. Without write access to the
/// device (it is root's), `check` and the daemon refuse the key, naming the device and the way
/// to grant it, and the rest is skipped.
#[test]
fn the_cpu_wake_up_latency_is_asked_for_while_the_daemon_runs() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let setup = town_setup(&["lidar"]);
    let text = std::fs::read_to_string(&setup.config).unwrap();
    std::fs::write(&setup.config, format!("cpu_dma_latency_us = 0\n{text}")).unwrap();
    let check = || {
        Command::new(daemon_binary().unwrap())
            .arg("check")
            .arg("--config")
            .arg(&setup.config)
            .output()
            .unwrap()
    };
    let refused = || {
        let out = check();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{err}");
        assert!(
            err.contains(cpu_latency::DEVICE) && err.contains("udev rule"),
            "{err}"
        );
    };
    let test = "the_cpu_wake_up_latency_is_asked_for_while_the_daemon_runs";
    let Some(before) = latency_before(test, refused) else {
        return;
    };
    let latency = kernel_latency;
    let out = check();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(said.contains("CPU wake-up latency 0 us"), "{said}");
    assert_eq!(latency(), before, "check asks nothing");
    let daemon = start(&setup);
    assert_eq!(latency(), 0);
    assert!(
        daemon.log().contains("cpu_dma_latency_us=0"),
        "{}",
        daemon.log()
    );
    daemon.kill().unwrap();
    assert_eq!(latency(), before, "a killed daemon's request ends with it");
    let daemon = start(&setup);
    assert_eq!(latency(), 0);
    assert!(daemon.stop().unwrap());
    assert_eq!(latency(), before);
}

/// `lanealign soak --cpu-dma-latency-us 0` has each phase's daemon ask for the latency: the
/// kernel's latency reads 0 while the soak runs and what it was after it, and the table's header
/// says so. Without write access to the device the soak fails naming it, and the rest is
/// skipped.
#[test]
fn a_soak_has_its_daemons_ask_for_the_cpu_wake_up_latency() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let soak = || {
        Command::new(env!("CARGO_BIN_EXE_lanealign"))
            .args(["soak", "--sources", "1", "--rate", "100", "--duration", "2"])
            .args(["--waits", "event", "--cpu-dma-latency-us", "0"])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    let refused = || {
        let out = soak().wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{err}");
        assert!(err.contains(cpu_latency::DEVICE), "{err}");
    };
    let test = "a_soak_has_its_daemons_ask_for_the_cpu_wake_up_latency";
    let Some(before) = latency_before(test, refused) else {
        return;
    };
    let latency = kernel_latency;
    let mut child = soak();
    let mut held = false;
    while child.try_wait().unwrap().is_none() {
        held |= latency() == 0;
        std::thread::sleep(Duration::from_millis(20));
    }
    let out = child.wait_with_output().unwrap();
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{said}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(said.contains("CPU wake-up latency 0 us"), "{said}");
    assert!(held, "the latency never read 0 while the soak ran");
    assert_eq!(latency(), before);
}

/// Always runs: SIGHUP reloads the tile. A running session keeps the tile it started with and
/// loses no pose; a session started after the reload uses the new tile.
/// Streams the town's drive through one session while, 300 poses in, `replace` changes the map
/// on disk and the daemon gets SIGHUP (and logs `reloaded`): no pose is lost, the running
/// session keeps its map (every answer as offline on the old map), and a new session corrects
/// on the new one (as offline on the new map's tile).
fn a_reload_keeps_running_sessions(
    setup: &Setup,
    name: &str,
    replace: impl FnOnce(),
    reloaded: &str,
) {
    let daemon = start(setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let before = offline(setup, name, &odometry);
    let mut running = connect(setup, name);
    wait_for_daemon(&mut running);
    let mut answers = Vec::new();
    let mut stream = |poses: &[Pose3]| {
        for p in poses {
            running.publish(0, &p.to_row_major()).unwrap();
            answers.extend(running.recv(Duration::from_secs(5)).unwrap());
        }
    };
    stream(&odometry[..300]);
    replace();
    hang_up(&daemon);
    let until = Instant::now() + Duration::from_secs(5);
    while !daemon.log().contains(reloaded) && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(daemon.log().contains(reloaded), "{}", daemon.log());
    stream(&odometry[300..]);
    assert_eq!(
        answers.len(),
        odometry.len(),
        "no pose lost across the reload"
    );
    assert!(
        poses_of(&answers) == before,
        "the running session kept its map"
    );
    let after = offline(setup, name, &odometry);
    assert!(after != before, "the new map changes corrections");
    // Flooded: a session on a grid that is behind waits for the cells it asked for, so that it
    // does not outrun its loader (before it did, this differed in 4 runs of 20 on busy cores).
    assert!(
        run_replay(setup, name, &odometry, Rate::Max(32)) == after,
        "a new session uses it"
    );
    assert!(daemon.stop().unwrap());
}

/// Always runs: SIGHUP loads the tile again for new sessions; the tile is rewritten in place.
#[test]
fn sighup_reloads_the_tile_for_new_sessions() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("reload");
    let setup = town_setup(&[&name]);
    let replace = || write_town_tile(&town_moved_north(), &setup.tile);
    a_reload_keeps_running_sessions(&setup, &name, replace, "tile reloaded");
}

/// Always runs: SIGHUP (`systemctl reload`) reloads the tile only, and says so when the
/// configuration file has changed since the start, naming what changed, and when it no longer
/// passes the checks (a restart would fail), naming the key; the daemon serves on as it started.
/// Before, an edited file and SIGHUP logged only "tile reloaded", as if the edit had been taken.
#[test]
fn sighup_tells_what_of_an_edited_configuration_takes_a_restart() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("edited");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let text = std::fs::read_to_string(&setup.config).unwrap();
    assert!(text.contains("max_sessions = 16\n"), "{text}");
    let reloads = |k: usize| {
        hang_up(&daemon);
        let until = Instant::now() + Duration::from_secs(5);
        while daemon.log().matches("tile reloaded").count() <= k {
            assert!(Instant::now() < until, "{}", daemon.log());
            std::thread::sleep(Duration::from_millis(20));
        }
        daemon.log()
    };
    let log = reloads(0);
    assert!(!log.contains("configuration file"), "{log}");
    // The file edited to `edited`, then the `k`-th SIGHUP: a line says `warning`, naming `what`.
    let told = |k: usize, edited: String, warning: &str, what: &str| {
        std::fs::write(&setup.config, edited).unwrap();
        let log = reloads(k);
        let line = log.lines().find(|l| l.contains(warning));
        assert!(line.is_some_and(|l| l.contains(what)), "{log}");
    };
    told(
        1,
        text.replace("max_sessions = 16", "max_sessions = 8"),
        "the configuration file changed since the daemon started",
        "changed=max_sessions",
    );
    told(
        2,
        text.replace("max_sessions = 16", "max_sesions = 8"),
        "the configuration file no longer passes the checks",
        "max_sesions",
    );
    let (_, odometry) = synthetic::drive(1, 5);
    assert!(
        run_replay(&setup, &name, &odometry[..300], Rate::Max(32))
            == offline(&setup, &name, &odometry[..300]),
        "the daemon serves on as it started"
    );
    assert!(daemon.stop().unwrap());
}

/// Always runs: SIGHUP reloads a grid too. The new grid is written into a new folder and the
/// link the configuration names is switched to it; the running session keeps reading the old
/// folder as it drives.
#[test]
fn sighup_reloads_a_grid_for_new_sessions() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("regrid");
    let setup = town_grid_setup(&[&name]);
    let replace = || {
        let dir = setup.dir.path();
        write_town_maps(&town_moved_north(), &setup.tile, &dir.join("town-grid-2"));
        std::os::unix::fs::symlink("town-grid-2", dir.join("town-grid.new")).unwrap();
        std::fs::rename(dir.join("town-grid.new"), dir.join("town-grid")).unwrap();
    };
    a_reload_keeps_running_sessions(&setup, &name, replace, "grid reloaded");
}

/// Always runs: sessions come and go (a client restarting over and over, each time a new
/// session that streams a few hundred poses and leaves without a word). Past `max_sessions` the
/// least recently active end once quiet for a second (a newcomer meanwhile waits for a place,
/// and ends a second after its client leaves), and what the daemon holds stays bounded: its open
/// files, its journals on disk and its shared-memory files are the same after 60 sessions as
/// after 30 (with waiting sessions kept until the next newcomer, CI once saw 270 open files
/// after 30 and 260 after 60).
/// Each is the median of 15 looks over 1.5 s, from 1 s after the last client left: the open
/// files dip by ten for up to a second after a client leaves, then settle (measured: 230, 230),
/// and the journal's background thread holds one or two more for a moment every second (one
/// look, on a busy disk, once saw 232 against 230); what leaks stays.
#[test]
fn sessions_that_come_and_go_leave_the_daemon_as_it_was() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("churn");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let now_held = || {
        let fds = std::fs::read_dir(format!("/proc/{}/fd", daemon.id()))
            .unwrap()
            .count();
        [
            fds,
            journal_count(&setup, &name),
            namespace(&setup).files().len(),
        ]
    };
    let held = || {
        std::thread::sleep(Duration::from_secs(1));
        let mut looks = Vec::new();
        for _ in 0..15 {
            looks.push(now_held());
            std::thread::sleep(Duration::from_millis(100));
        }
        std::array::from_fn::<usize, 3, _>(|i| {
            let mut each: Vec<usize> = looks.iter().map(|l| l[i]).collect();
            each.sort();
            each[each.len() / 2]
        })
    };
    let mut counts = Vec::new();
    for k in 0..60 {
        let mut conn = connect(&setup, &name);
        wait_for_daemon(&mut conn);
        for p in &odometry[..600] {
            conn.publish(0, &p.to_row_major()).unwrap();
            let answer = conn.recv(Duration::from_secs(5)).unwrap();
            assert!(answer.is_some(), "session {k}: every pose answered");
        }
        drop(conn);
        if k == 29 || k == 59 {
            counts.push(held());
        }
    }
    println!("open files, journals, shared-memory files after 30 and 60 sessions: {counts:?}");
    assert_eq!(
        counts[0], counts[1],
        "(open files, journals, shared-memory files)"
    );
    assert!(daemon.stop().unwrap());
}

/// Always runs: a client that closes its session (`Connection::close`) gets the answers still in
/// flight, and the daemon forgets the session at once instead of after `session_timeout_s`: its
/// journal and its answer service are gone, the metrics count it closed, and a session of the
/// same source streaming before and after is answered as offline. A goodbye for a session the
/// daemon does not run starts none.
#[test]
fn a_closed_session_is_forgotten_at_once() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("close");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let expected = offline(&setup, &name, &odometry);
    let journals = || journal_count(&setup, &name);
    let until_within = |what: &str, done: &dyn Fn() -> bool| {
        let until = Instant::now() + Duration::from_secs(5);
        while !done() && Instant::now() < until {
            std::thread::sleep(Duration::from_millis(20));
        }
        assert!(done(), "{what}\n{}", daemon.log());
    };

    let mut beside = connect(&setup, &name);
    wait_for_daemon(&mut beside);
    let half = odometry.len() / 2;
    let mut beside_answers: Vec<_> = odometry[..half]
        .iter()
        .map(|p| answer_of(&mut beside, p))
        .collect();
    let (files_before, journals_before) = (namespace(&setup).files(), journals());

    let (total, in_flight) = (600, 20);
    let mut closing = connect(&setup, &name);
    let mut answered: Vec<u64> = odometry[..total - in_flight]
        .iter()
        .map(|p| answer_of(&mut closing, p).seq)
        .collect();
    for p in &odometry[total - in_flight..total] {
        closing.publish(0, &p.to_row_major()).unwrap();
    }
    assert_eq!(
        journals(),
        journals_before + 1,
        "the closing session is journaled"
    );
    let closed = closing.close(Duration::from_secs(5)).unwrap();
    assert!(closed.daemon_told, "the daemon took the goodbye");
    assert!(closed.unanswered.is_empty(), "{:?}", closed.unanswered);
    answered.extend(closed.answers.iter().map(|a| a.seq));
    assert_eq!(
        answered,
        (1..=total as u64).collect::<Vec<_>>(),
        "every pose answered once, the last {in_flight} by close"
    );
    until_within("the closed session's journal removed", &|| {
        journals() == journals_before
    });
    until_within("the closed session's shared memory gone", &|| {
        namespace(&setup).files() == files_before
    });
    until_within("the metrics count the closed session", &|| {
        daemon.log().contains("closed_sessions=1")
    });

    let stranger = RawClient::new(&setup, &name);
    assert!(stranger.goodbye(1), "the daemon takes a stranger's goodbye");
    beside_answers.extend(odometry[half..].iter().map(|p| answer_of(&mut beside, p)));
    assert_eq!(journals(), journals_before, "a goodbye starts no session");
    assert!(
        poses_of(&beside_answers) == expected,
        "the session beside answered as offline"
    );
    assert!(daemon.stop().unwrap());
}

/// Always runs: a client that closes while its daemon is dead (killed with poses in flight)
/// loses none without saying so: `close` names exactly the poses no answer came for, and says
/// no daemon took the goodbye.
#[test]
fn closing_without_a_daemon_names_what_was_not_answered() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("orphan");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let mut conn = connect(&setup, &name);
    wait_for_daemon(&mut conn);
    for p in &odometry[..100] {
        answer_of(&mut conn, p);
    }
    daemon.kill().unwrap();
    for p in &odometry[100..110] {
        conn.publish(0, &p.to_row_major()).unwrap();
    }
    let closed = conn.close(Duration::from_millis(300)).unwrap();
    assert!(closed.answers.is_empty(), "{:?}", closed.answers);
    assert_eq!(closed.unanswered, (101..=110).collect::<Vec<u64>>());
    assert!(!closed.daemon_told, "no daemon took the goodbye");
    remove_namespace_files(&setup.namespace);
}

/// Always runs: a client that floods its session and never reads an answer (a hung odometry
/// process, or one on the raw wire that ignores the protocol) holds up no one. A session of
/// the same source streaming beside it gets every answer, equal to offline correction; the
/// flooder's answers beyond what its subscriber holds are dropped, not waited for, and counted.
#[test]
fn a_client_that_never_reads_holds_up_no_one() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("noreader");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let expected = offline(&setup, &name, &odometry);
    let flooder = RawClient::new(&setup, &name);
    let mut conn = connect(&setup, &name);
    wait_for_daemon(&mut conn);
    let (mut answers, mut flooded, mut taken) = (Vec::new(), 0u64, 0u64);
    for p in &odometry {
        for _ in 0..4 {
            flooded += 1;
            let pose = odometry[(flooded as usize - 1) % odometry.len()];
            taken += u64::from(flooder.send_only(flooded, pose.to_row_major()));
        }
        conn.publish(0, &p.to_row_major()).unwrap();
        let answer = conn.recv(Duration::from_secs(5)).unwrap();
        answers.push(answer.expect("an answer within 5 s, the flooder beside it"));
    }
    assert!(poses_of(&answers) == expected, "answers as offline");
    let undelivered = || -> u64 {
        daemon
            .log()
            .split("undelivered=")
            .skip(1)
            .filter_map(|rest| rest.split(' ').next()?.parse::<u64>().ok())
            .sum()
    };
    let held = lanealign_wire::service::BUFFER_SIZE as u64;
    assert!(
        taken > 2 * held,
        "the flooder sent more than its answers fill: {taken}"
    );
    let until = Instant::now() + Duration::from_secs(5);
    while undelivered() < taken - held && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(50));
    }
    assert_eq!(
        undelivered(),
        taken - held,
        "every answer beyond the flooder's buffer counted as undelivered\n{}",
        daemon.log()
    );
    assert!(daemon.stop().unwrap());
}

/// Always runs: a SIGHUP that finds a bad tile in the configured place (a byte flipped, cut
/// short, of a lane geometry the sources' correctors refuse, removed) is refused with an error
/// naming the problem, and the daemon goes on serving the tile it has: every new session after
/// each refused reload corrects exactly as before.
#[test]
fn a_bad_tile_on_sighup_keeps_the_one_the_daemon_has() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("badreload");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let expected = offline(&setup, &name, &odometry);
    let good = std::fs::read(&setup.tile).unwrap();
    let mut flipped = good.clone();
    let middle = flipped.len() / 2;
    flipped[middle] ^= 0x10;
    let map = lanealign_core::lane_map::LaneMap::new(&synthetic::town_lanes()).unwrap();
    let geometry = lanealign_core::lane_geometry::LaneGeometry {
        unmarked_offset_scale: Some(1.0),
        ..synthetic::town_geometry()
    };
    let other_geometry =
        lanealign_core::tile::encode(&map, &synthetic::town_plane(), 3.0, &geometry);
    // What the configured place holds at each reload (`None`: nothing), and what the refusal names.
    let cases = [
        ("a byte flipped", Some(flipped), "checksum mismatch"),
        (
            "cut short",
            Some(good[..good.len() / 3].to_vec()),
            "truncated",
        ),
        (
            "another lane geometry",
            Some(other_geometry),
            "unmarked-street offset scale 1,",
        ),
        ("removed", None, "No such file"),
    ];
    for (k, (what, bytes, named)) in cases.iter().enumerate() {
        match bytes {
            Some(bytes) => std::fs::write(&setup.tile, bytes).unwrap(),
            None => std::fs::remove_file(&setup.tile).unwrap(),
        }
        assert_reload_refused(&daemon, k, "the tile was not reloaded", what, named);
        assert!(
            run_replay(&setup, &name, &odometry, Rate::Max(32)) == expected,
            "{what}: a new session corrects on the tile the daemon has"
        );
        std::fs::write(&setup.tile, &good).unwrap();
    }
    assert!(!daemon.log().contains("tile reloaded"), "{}", daemon.log());
    assert!(daemon.stop().unwrap());
}

/// Always runs: the same for a grid. The configured link switched to a grid folder with its
/// manifest cut short, with every cell's bytes changed, without a manifest, or with a far cell
/// listed at more bytes than a tile may have: each reload is refused naming the problem, and
/// new sessions correct on the grid the daemon has.
#[test]
fn a_bad_grid_on_sighup_keeps_the_one_the_daemon_has() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("badregrid");
    let setup = town_grid_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let expected = offline(&setup, &name, &odometry);
    let map = lanealign_core::lane_map::LaneMap::new(&synthetic::town_lanes()).unwrap();
    let dir = setup.dir.path();
    let manifest = |grid: &std::path::Path| grid.join(lanealign_core::grid::MANIFEST);
    type Damage = fn(&std::path::Path);
    let cases: [(&str, Damage, &str); 4] = [
        (
            "manifest cut short",
            |grid| {
                let path = grid.join(lanealign_core::grid::MANIFEST);
                let text = std::fs::read(&path).unwrap();
                std::fs::write(&path, &text[..text.len() / 2]).unwrap();
            },
            "manifest",
        ),
        (
            "every cell changed",
            |grid| {
                let cells = std::fs::read_dir(grid.join("cells")).unwrap().flatten();
                for cell in cells.map(|entry| entry.path()) {
                    let mut bytes = std::fs::read(&cell).unwrap();
                    let middle = bytes.len() / 2;
                    bytes[middle] ^= 0x10;
                    std::fs::write(&cell, bytes).unwrap();
                }
            },
            "checksum",
        ),
        (
            "no manifest",
            |grid| std::fs::remove_file(grid.join(lanealign_core::grid::MANIFEST)).unwrap(),
            "manifest",
        ),
        (
            // Far from every source, so never loaded: until 2026-12-03 the lengths' sum
            // overflowed and the daemon aborted.
            "a far cell listed at 2^64 - 1 bytes",
            |grid| {
                let path = grid.join(lanealign_core::grid::MANIFEST);
                let mut text = std::fs::read_to_string(&path).unwrap();
                text.push_str(&format!(
                    "\n[[cells]]\nx = 100000\ny = 100000\nchecksum = \"0123456789abcdef\"\n\
                     bytes = {}\npoints = 1\n",
                    u64::MAX
                ));
                std::fs::write(&path, text).unwrap();
            },
            "longer than a tile",
        ),
    ];
    for (k, (what, damage, named)) in cases.iter().enumerate() {
        let folder = dir.join(format!("bad-grid-{k}"));
        write_town_maps(&map, &dir.join(format!("bad-{k}.tile")), &folder);
        assert!(manifest(&folder).is_file());
        damage(&folder);
        std::os::unix::fs::symlink(format!("bad-grid-{k}"), dir.join("town-grid.new")).unwrap();
        std::fs::rename(dir.join("town-grid.new"), dir.join("town-grid")).unwrap();
        assert_reload_refused(&daemon, k, "the grid was not reloaded", what, named);
        assert!(
            run_replay(&setup, &name, &odometry, Rate::Max(32)) == expected,
            "{what}: a new session corrects on the grid the daemon has"
        );
    }
    assert!(!daemon.log().contains("grid reloaded"), "{}", daemon.log());
    assert!(daemon.stop().unwrap());
}

/// Always runs: neither SIGHUP nor a restart goes back to an older map. A tile, then a grid, of
/// an older map version put in the configured place (a rollback: a signature would not tell, it
/// names the builder) is refused naming both versions, and new sessions correct on the map
/// served; a newer one is loaded, and from then on the version it replaced is the older one,
/// also for `check` and a daemon started after a kill -9, until the record is removed.
#[test]
fn an_older_map_is_refused_on_sighup_and_on_restart() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let (_, odometry) = synthetic::drive(1, 42);
    let town = lanealign_core::lane_map::LaneMap::new(&synthetic::town_lanes()).unwrap();
    let versioned = |map: &lanealign_core::lane_map::LaneMap, version: u64| {
        let mut bytes = lanealign_core::tile::encode(
            map,
            &synthetic::town_plane(),
            3.0,
            &synthetic::town_geometry(),
        );
        lanealign_core::tile::set_map_version(&mut bytes, version).unwrap();
        bytes
    };
    let name = unique("rollback");
    let setup = town_setup(&[&name]);
    std::fs::write(&setup.tile, versioned(&town, 5)).unwrap();
    let daemon = start(&setup);
    assert!(daemon.log().contains("map_version=5"), "{}", daemon.log());
    let on_town = offline(&setup, &name, &odometry);
    let refusal = "the tile was not reloaded";
    std::fs::write(&setup.tile, versioned(&town_moved_north(), 4)).unwrap();
    let older = "map version 4 is older than the served map's 5";
    assert_reload_refused(&daemon, 0, refusal, "version 4", older);
    assert!(
        run_replay(&setup, &name, &odometry, Rate::Max(32)) == on_town,
        "a new session corrects on the tile served"
    );
    std::fs::write(&setup.tile, versioned(&town_moved_north(), 6)).unwrap();
    let on_moved = offline(&setup, &name, &odometry);
    assert!(on_moved != on_town, "the moved map changes corrections");
    hang_up(&daemon);
    let until = Instant::now() + Duration::from_secs(5);
    while !daemon.log().contains("tile reloaded") && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(daemon.log().contains("map_version=6"), "{}", daemon.log());
    std::fs::write(&setup.tile, versioned(&town, 5)).unwrap();
    let older = "map version 5 is older than the served map's 6";
    assert_reload_refused(&daemon, 1, refusal, "version 5 after 6", older);
    assert!(
        run_replay(&setup, &name, &odometry, Rate::Max(32)) == on_moved,
        "a new session corrects on the tile served, version 6"
    );
    // Killed, the daemon cannot be made to go back by a restart either: version 6 was recorded
    // before it was served.
    daemon.kill().unwrap();
    let older = "map version 5 is older than 6, the newest this namespace's daemon has served";
    let checked = Command::new(daemon_binary().unwrap())
        .args(["check", "--config"])
        .arg(&setup.config)
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&checked.stderr);
    assert!(!checked.status.success() && said.contains(older), "{said}");
    let log = setup.dir.path().join("restart.log");
    let restarted = DaemonProcess::start_ready(&setup.config, &log, Duration::from_secs(20));
    let Err(DaemonProcessError::NotReady { log, .. }) = restarted else {
        panic!("a restart on version 5 after 6 must be refused");
    };
    assert!(log.contains(older), "{log}");
    let record = served_map_record(&setup);
    assert_eq!(std::fs::read_to_string(&record).unwrap(), "6\n");
    std::fs::remove_file(&record).unwrap();
    let daemon = start(&setup);
    assert!(
        run_replay(&setup, &name, &odometry, Rate::Max(32)) == on_town,
        "the record removed, a restart goes back to version 5 deliberately"
    );
    assert!(daemon.stop().unwrap());
    assert_eq!(std::fs::read_to_string(&record).unwrap(), "5\n");

    let name = unique("regridback");
    let setup = town_grid_setup(&[&name]);
    let dir = setup.dir.path();
    let switch_to = |folder: &str| {
        std::os::unix::fs::symlink(folder, dir.join("town-grid.new")).unwrap();
        std::fs::rename(dir.join("town-grid.new"), dir.join("town-grid")).unwrap();
    };
    write_town_grid(&town, &dir.join("v5"), 5);
    switch_to("v5");
    let daemon = start(&setup);
    let on_town = offline(&setup, &name, &odometry);
    write_town_grid(&town_moved_north(), &dir.join("v4"), 4);
    switch_to("v4");
    let older = "map version 4 is older than the served map's 5";
    assert_reload_refused(&daemon, 0, "the grid was not reloaded", "grid 4", older);
    assert!(
        run_replay(&setup, &name, &odometry, Rate::Max(32)) == on_town,
        "a new session corrects on the grid served"
    );
    assert!(!daemon.log().contains("grid reloaded"), "{}", daemon.log());
    let record = served_map_record(&setup);
    let recorded = || std::fs::read_to_string(&record).unwrap();
    assert_eq!(recorded(), "5\n", "the grid started on is recorded");
    write_town_grid(&town_moved_north(), &dir.join("v6"), 6);
    switch_to("v6");
    hang_up(&daemon);
    let log = log_once_it_says(&daemon, "grid reloaded");
    assert!(log.contains("grid reloaded"), "{log}");
    assert_eq!(recorded(), "6\n", "a grid loaded on SIGHUP is recorded");
    assert!(daemon.stop().unwrap());
}

/// Sends SIGHUP to `daemon`: load the map again.
fn hang_up(daemon: &DaemonProcess) {
    signal(daemon.id(), Signal::HUP);
}

/// Sends SIGHUP to `daemon` and asserts that its `k`-th (from 0) log line saying `refusal`
/// comes within 5 s and names `named`.
fn assert_reload_refused(daemon: &DaemonProcess, k: usize, refusal: &str, what: &str, named: &str) {
    hang_up(daemon);
    let refusals = || daemon.log().matches(refusal).count();
    let until = Instant::now() + Duration::from_secs(5);
    while refusals() <= k && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(20));
    }
    let log = daemon.log();
    let line = log.lines().filter(|l| l.contains(refusal)).nth(k);
    assert!(
        line.is_some_and(|l| l.contains(named)),
        "{what}: refused naming '{named}'\n{log}"
    );
}

/// The daemon never shares its fate with the tile file: truncated in place and then removed
/// while a session streams, every pose is still answered exactly as before, and the log says
/// what happened to the file.
#[test]
fn a_tile_changed_under_the_daemon_changes_nothing_but_the_log() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("tilefile");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let expected = offline(&setup, &name, &odometry);
    let mut conn = connect(&setup, &name);
    wait_for_daemon(&mut conn);
    let mut answers = Vec::new();
    let wait_for_log = |what: &str| {
        let until = Instant::now() + Duration::from_secs(5);
        while !daemon.log().contains(what) && Instant::now() < until {
            std::thread::sleep(Duration::from_millis(20));
        }
        assert!(daemon.log().contains(what), "{}", daemon.log());
    };
    let thirds = [
        0,
        odometry.len() / 3,
        2 * odometry.len() / 3,
        odometry.len(),
    ];
    for (k, part) in thirds.windows(2).enumerate() {
        for p in &odometry[part[0]..part[1]] {
            conn.publish(0, &p.to_row_major()).unwrap();
            answers.extend(conn.recv(Duration::from_secs(5)).unwrap());
        }
        match k {
            0 => {
                let file = std::fs::OpenOptions::new()
                    .write(true)
                    .open(&setup.tile)
                    .unwrap();
                file.set_len(100).unwrap();
                wait_for_log("truncated in place (100 of");
            }
            1 => {
                std::fs::remove_file(&setup.tile).unwrap();
                wait_for_log("change=\"removed\"");
            }
            _ => {}
        }
    }
    assert_eq!(answers.len(), odometry.len(), "every pose answered");
    assert!(
        poses_of(&answers) == expected,
        "answers as from the intact tile"
    );
    assert!(daemon.stop().unwrap());
}

/// The access model: a deployment's daemon and clients run as one user. A client of another
/// user is told whose namespace it is and what to do, and can run a deployment of its own in
/// another namespace. Needs root (to be another user with runuser): visibly skipped otherwise.
#[test]
fn a_client_of_another_user_is_told_whose_namespace_it_is() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    if !root_with(
        "a_client_of_another_user_is_told_whose_namespace_it_is",
        &["runuser"],
    ) {
        return;
    }
    let name = unique("access");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    // A trajectory the other user can read.
    let shared = tempfile::Builder::new()
        .prefix("lanealign-access")
        .tempdir_in("/tmp")
        .unwrap();
    std::fs::set_permissions(
        shared.path(),
        std::os::unix::fs::PermissionsExt::from_mode(0o755),
    )
    .unwrap();
    let input = shared.path().join("in.txt");
    let (_, odometry) = synthetic::drive(1, 1);
    write_kitti(&input, &odometry[..10]);
    std::fs::set_permissions(&input, std::os::unix::fs::PermissionsExt::from_mode(0o644)).unwrap();
    let as_nobody = |namespace: &str| {
        let out = Command::new("runuser")
            .args([
                "-u",
                "nobody",
                "--",
                env!("CARGO_BIN_EXE_lanealign"),
                "replay",
                "--source",
                &name,
                "--namespace",
                namespace,
                "--wait-for-daemon",
                "0.5",
            ])
            .arg(&input)
            .arg("-o")
            .arg(shared.path().join("out.txt"))
            .output()
            .unwrap();
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).to_string()
    };
    let err = as_nobody(&setup.namespace);
    assert!(
        err.contains("belong to 'root' (uid 0)") && err.contains("another namespace"),
        "{err}"
    );
    // In a namespace of its own the other user connects (there is just no daemon there).
    let own = unique_namespace('n');
    let err = as_nobody(&own);
    assert!(
        err.contains(&format!("no daemon runs in namespace '{own}'")),
        "{err}"
    );
    remove_namespace_files(&own);
    assert!(daemon.stop().unwrap());
}

/// Always runs: a replay that finds no daemon serving its source says what the namespace holds
/// instead: the sources its daemon serves when the name is another (a typo, a source not
/// configured), or that no daemon runs there (another namespace). Before, both said only "no
/// daemon is serving source '...'", while a daemon served the namespace.
#[test]
fn a_replay_nobody_serves_is_told_what_there_is() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("served");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let input = setup.dir.path().join("in.txt");
    let (_, odometry) = synthetic::drive(1, 1);
    write_kitti(&input, &odometry[..10]);
    let refused = |source: &str, namespace: &str| {
        let out = Command::new(env!("CARGO_BIN_EXE_lanealign"))
            .args(["replay", "--source", source, "--namespace", namespace])
            .args(["--wait-for-daemon", "0.5"])
            .arg(&input)
            .arg("-o")
            .arg(setup.dir.path().join("out.txt"))
            .output()
            .unwrap();
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).to_string()
    };
    let namespace = &setup.namespace;
    let err = refused("no-such-source", namespace);
    assert!(
        err.contains(&format!(
            "the daemon of namespace '{namespace}' serves '{name}', not 'no-such-source'"
        )),
        "{err}"
    );
    let elsewhere = unique_namespace('e');
    let err = refused(&name, &elsewhere);
    assert!(
        err.contains(&format!("no daemon runs in namespace '{elsewhere}'")),
        "{err}"
    );
    remove_namespace_files(&elsewhere);
    assert!(daemon.stop().unwrap());
}

/// Always runs: under systemd (`Type=notify`) the daemon says when it is ready, feeds the
/// watchdog while its workers run, and says when it stops: checked on a socket standing in for
/// systemd's.
#[test]
fn systemd_hears_ready_watchdog_and_stopping() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let setup = town_setup(&[&unique("notify")]);
    let (socket_path, socket) = notify_socket(&setup, Duration::from_secs(10));
    let mut daemon = Command::new(daemon_binary().unwrap())
        .arg("--config")
        .arg(&setup.config)
        .env("NOTIFY_SOCKET", &socket_path)
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut heard = Vec::new();
    hear_until(&socket, &mut heard, "WATCHDOG=1");
    assert!(
        heard[0].contains("READY=1") && heard[0].contains("STATUS=serving 1 sources"),
        "{heard:?}"
    );
    signal(daemon.id(), Signal::TERM);
    hear_until(&socket, &mut heard, "STOPPING=1");
    assert!(daemon.wait().unwrap().success());
}

/// A socket standing in for systemd's (`NOTIFY_SOCKET`) in `setup`'s folder, its path, and each
/// receive waiting at most `timeout`.
fn notify_socket(setup: &Setup, timeout: Duration) -> (PathBuf, UnixDatagram) {
    let path = setup.dir.path().join("notify.sock");
    let socket = UnixDatagram::bind(&path).unwrap();
    socket.set_read_timeout(Some(timeout)).unwrap();
    (path, socket)
}

/// Adds what `socket` hears to `heard` until a notification says `what`.
fn hear_until(socket: &UnixDatagram, heard: &mut Vec<String>, what: &str) {
    let mut buf = [0u8; 512];
    while !heard.last().is_some_and(|m| m.contains(what)) {
        let n = socket
            .recv(&mut buf)
            .unwrap_or_else(|e| panic!("{what} not heard: {e} ({heard:?})"));
        heard.push(String::from_utf8_lossy(&buf[..n]).into_owned());
    }
}

/// Always runs: a request to stop is heard while the workers start. 256 sources take about two
/// seconds to start here; SIGTERM sent as the tile is loaded stops the daemon without its ever
/// saying it is ready (neither in its log nor to systemd), where it used to be deaf until every
/// worker had started, tell systemd `READY=1` after the request, and only then stop.
#[test]
fn a_stop_request_while_the_workers_start_is_heard() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let names: Vec<String> = (0..256).map(|i| unique(&format!("early{i}"))).collect();
    let setup = town_setup(&names.iter().map(String::as_str).collect::<Vec<_>>());
    let (socket_path, socket) = notify_socket(&setup, Duration::from_secs(30));
    let log = setup.dir.path().join("early.log");
    let mut daemon = KillOnDrop(
        Command::new(daemon_binary().unwrap())
            .arg("--config")
            .arg(&setup.config)
            .env("NOTIFY_SOCKET", &socket_path)
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap(),
    );
    let deadline = Instant::now() + Duration::from_secs(30);
    while !std::fs::read_to_string(&log).is_ok_and(|text| text.contains("tile loaded")) {
        assert!(Instant::now() < deadline, "no tile loaded within 30 s");
        std::thread::sleep(Duration::from_millis(5));
    }
    signal(daemon.0.id(), Signal::TERM);
    let mut heard = Vec::new();
    hear_until(&socket, &mut heard, "STOPPING=1");
    let status = daemon.0.wait().unwrap();
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(status.success(), "{status}\n{text}");
    assert!(!heard.iter().any(|m| m.contains("READY=1")), "{heard:?}");
    assert!(
        text.contains("asked to stop while the sources' workers started")
            && !text.contains(" ready "),
        "{text}"
    );
}

/// Always runs: a request to stop is not lost to the signal after it. systemd stops a service
/// with SIGTERM and at once SIGCONT (so that a stopped process can act on it), and a shell's
/// `kill -INT` then `fg` does the same. iceoryx2 kept one "last signal" for both: when the
/// request reached a thread other than the one waiting to read it (the kernel picks any thread
/// of a busy process), SIGCONT overwrote it and the daemon served on until systemd killed it at
/// `TimeoutStopSec`. Injected deterministically: the request sent to a worker's thread
/// (`tgkill`), then SIGCONT to the process. Each time it shuts down cleanly within 5 s. The
/// daemon catches no signal but those it acts on (iceoryx2's handlers swallowed SIGCONT, SIGTSTP,
/// SIGQUIT, SIGUSR1 and more).
#[test]
fn a_stop_request_followed_by_sigcont_stops_the_daemon() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("sigcont");
    let setup = town_setup(&[&name]);
    let (_, odometry) = synthetic::drive(1, 8);
    for request in [Signal::TERM, Signal::INT] {
        let log = setup.dir.path().join("sigcont.log");
        let mut daemon = daemon_logging_to(&setup, std::fs::File::create(&log).unwrap());
        let client = served(&setup, &name, &odometry[0]);
        let caught = caught_signals(daemon.0.id());
        for swallowed in [Signal::CONT, Signal::TSTP, Signal::QUIT, Signal::USR1] {
            assert!(
                !caught.contains(&(swallowed.as_raw() as u32)),
                "the daemon catches {swallowed:?}: {caught:?}"
            );
        }
        let worker = thread_named(daemon.0.id(), "worker-");
        // SAFETY: tgkill takes plain integers and touches no memory of this process.
        let sent = unsafe {
            libc::syscall(
                libc::SYS_tgkill,
                daemon.0.id() as libc::pid_t,
                worker,
                request.as_raw(),
            )
        };
        assert_eq!(sent, 0, "tgkill {request:?}");
        signal(daemon.0.id(), Signal::CONT);
        let deadline = Instant::now() + Duration::from_secs(5);
        let status = loop {
            if let Some(status) = daemon.0.try_wait().unwrap() {
                break status;
            }
            if Instant::now() > deadline {
                panic!(
                    "{request:?} then SIGCONT: the daemon still runs after 5 s\n{}",
                    std::fs::read_to_string(&log).unwrap_or_default()
                );
            }
            std::thread::sleep(Duration::from_millis(10));
        };
        let text = std::fs::read_to_string(&log).unwrap();
        assert!(status.success(), "{request:?}: {status}\n{text}");
        assert!(text.contains("shutting down"), "{request:?}:\n{text}");
        drop(client);
    }
}

/// The numbers of the signals process `pid` has handlers for (`SigCgt` in `/proc`).
fn caught_signals(pid: u32) -> Vec<u32> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let mask = status
        .lines()
        .find_map(|line| line.strip_prefix("SigCgt:"))
        .and_then(|hex| u64::from_str_radix(hex.trim(), 16).ok())
        .expect("/proc/PID/status has SigCgt");
    (1..=64).filter(|n| mask >> (n - 1) & 1 == 1).collect()
}

/// The id of the first thread of process `pid` whose name starts with `prefix`.
fn thread_named(pid: u32, prefix: &str) -> libc::pid_t {
    let tasks = std::fs::read_dir(format!("/proc/{pid}/task")).unwrap();
    tasks
        .map(|task| task.unwrap().path())
        .find(|task| {
            std::fs::read_to_string(task.join("comm")).is_ok_and(|name| name.starts_with(prefix))
        })
        .and_then(|task| task.file_name()?.to_str()?.parse().ok())
        .unwrap_or_else(|| panic!("process {pid} has no thread named {prefix}..."))
}

/// Always runs: a log nobody reads holds up no answer. The daemon's stderr is a pipe of one
/// page, filled before it starts and not read (a stalled journald, a paused terminal, a `| less`
/// left alone): every pose of a session is answered as offline, and the daemon stops cleanly
/// when asked. The records it made meanwhile come out once the pipe is read. (Writing them on
/// the workers' threads, it never became ready: its first record blocked.)
#[test]
fn a_log_nobody_reads_holds_up_no_answer() {
    use std::io::{Read, Write};
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("logpipe");
    let setup = town_setup(&[&name]);
    let (reader, writer) = rustix::pipe::pipe().unwrap();
    let room = rustix::pipe::fcntl_setpipe_size(&writer, 4096).unwrap();
    let mut writer = std::fs::File::from(writer);
    writer.write_all(&vec![b'#'; room]).unwrap();
    let mut daemon = daemon_logging_to(&setup, writer);
    let (_, odometry) = synthetic::drive(1, 9);
    let got = run_replay(&setup, &name, &odometry, Rate::Hz(1000.0));
    assert!(got == offline(&setup, &name, &odometry));
    let reading = std::thread::spawn(move || {
        let mut text = String::new();
        std::fs::File::from(reader)
            .read_to_string(&mut text)
            .unwrap();
        text
    });
    signal(daemon.0.id(), Signal::TERM);
    assert!(daemon.0.wait().unwrap().success());
    let log = reading.join().unwrap();
    for record in ["ready", "worker started", "shutting down"] {
        assert!(
            log.contains(record),
            "'{record}' in the log once read:\n{log}"
        );
    }
}

/// Always runs: two clients stream to a source set for one session (`max_sessions = 1`), pose by
/// pose in turn. The first keeps its corrector, answered as offline; the second waits for a
/// place, told once in the log: its poses come back as they went (`pass_through`, reason
/// `sessions_full`) until the first closes, and from its next pose on it is corrected as a
/// session that begins there. Before, each client's pose ended the other's session: both were
/// answered `gap` and started afresh pose after pose, and neither was ever corrected (600 poses
/// each at 100 Hz: 0 accepted, 362 and 387 fresh starts, an INFO line for each end).
#[test]
fn a_session_beyond_max_sessions_waits_while_the_others_stream() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("full");
    let setup = town_setup(&[&name]);
    let text = std::fs::read_to_string(&setup.config).unwrap();
    assert!(text.contains("max_sessions = 16"), "{text}");
    std::fs::write(
        &setup.config,
        text.replace("max_sessions = 16", "max_sessions = 1"),
    )
    .unwrap();
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 42);
    let (both, alone) = odometry[..400].split_at(300);
    let mut first = connect(&setup, &name);
    let mut second = connect(&setup, &name);
    wait_for_daemon(&mut first);
    wait_for_daemon(&mut second);
    let mut answers = (Vec::new(), Vec::new());
    for pose in both {
        answers.0.push(answer_of(&mut first, pose));
        answers.1.push(answer_of(&mut second, pose));
    }
    assert!(
        poses_of(&answers.0) == offline(&setup, &name, both),
        "the first session keeps its corrector"
    );
    for (answer, pose) in answers.1.iter().zip(both) {
        assert_eq!(
            (answer.status, answer.reason, answer.pose),
            (
                StatusCode::PassThrough as u32,
                ReasonCode::SessionsFull as u32,
                pose.to_row_major()
            ),
            "seq {}",
            answer.seq
        );
    }
    closed(first, &daemon, 0);
    let later: Vec<CorrectedPose> = alone.iter().map(|p| answer_of(&mut second, p)).collect();
    assert!(
        poses_of(&later) == offline(&setup, &name, alone),
        "the second session is corrected from the pose that found the place"
    );
    // What `lanealign replay` tells of the second session's answers.
    let all: Vec<CorrectedPose> = answers.1.iter().chain(&later).copied().collect();
    let told = waited_for_place_warning(&all).expect("the wait is told");
    assert!(
        told.starts_with("300 poses (sequence numbers 1 to 300) came back uncorrected"),
        "{told}"
    );
    assert_eq!(waited_for_place_warning(&answers.0), None);
    // Once the second session's end is in the log, so is what was said before it.
    closed(second, &daemon, 1);
    let log = daemon.log();
    assert_eq!(
        log.matches("a new session waits for a place").count(),
        1,
        "{log}"
    );
    assert_eq!(
        log.matches("a session that waited has a place").count(),
        1,
        "{log}"
    );
    assert!(daemon.stop().unwrap(), "clean exit");
}

/// Always runs: a source takes at most `MAX_POSE_PUBLISHERS` clients at once (iceoryx2 fixes its
/// pose service's publishers when it is made); the next is refused with a message that says so
/// and what to do (it was iceoryx2's `ExceedsMaxSupportedPublishers`), and once one of them
/// closes, a new client is served. `max_sessions` above that limit counts sessions whose clients
/// have left.
#[test]
fn a_source_with_all_its_clients_says_so_to_the_next() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("full");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 10);
    let mut clients: Vec<Connection> = (0..lanealign_wire::service::MAX_POSE_PUBLISHERS)
        .map(|_| served(&setup, &name, &odometry[0]))
        .collect();
    let refused =
        Connection::connect_in(&namespace(&setup), &name.parse().unwrap(), new_session_id())
            .err()
            .map(|e| lanealign_core::report::error_chain(&e))
            .expect("the source is full");
    assert!(
        refused.contains(&format!(
            "source '{name}' has {} clients connected, the most one source takes",
            lanealign_wire::service::MAX_POSE_PUBLISHERS
        )),
        "{refused}"
    );
    let closed = clients
        .pop()
        .unwrap()
        .close(Duration::from_secs(1))
        .unwrap();
    assert!(closed.daemon_told && closed.unanswered.is_empty());
    clients.push(served(&setup, &name, &odometry[0]));
    drop(clients);
    assert!(daemon.stop().unwrap());
}

/// Always runs: a client publishing far faster than the daemon corrects (a million poses a
/// second asked for) is held back by the connection, not dropped: every pose answered once,
/// equal to offline correction.
#[test]
fn overload_is_held_back_not_lost() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("flood");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(2, 5);
    let got = run_replay(&setup, &name, &odometry, Rate::Hz(1e6));
    assert!(got == offline(&setup, &name, &odometry));
    assert!(daemon.stop().unwrap());
}

/// Always runs: a cleaner of old temporary files does not cut a serving daemon off. systemd's
/// stock rule for `/tmp` (`q /tmp 1777 root root 10d`: Fedora, Arch, Yocto) removes what nobody
/// touched for 10 days, which includes the node and service records a daemon writes once at
/// start; a namespace keeps nothing in `/tmp`. Injected as that cleaner acts, by removing from
/// `/tmp` everything that names the namespace while the daemon serves; a client that starts
/// after it is served, and so is the one before. (With the namespace's folder in `/tmp`, the
/// client after found no daemon.)
#[test]
fn a_cleaner_of_tmp_cuts_no_client_off() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("tmpclean");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 7);
    let mut before = served(&setup, &name, &odometry[0]);
    let files = namespace(&setup).files();
    assert!(
        !files.is_empty() && files.iter().all(|f| f.starts_with("/dev/shm")),
        "{files:?}"
    );
    for entry in std::fs::read_dir("/tmp").unwrap().flatten() {
        if entry
            .file_name()
            .to_string_lossy()
            .contains(&setup.namespace)
        {
            let path = entry.path();
            let _ = std::fs::remove_dir_all(&path).or_else(|_| std::fs::remove_file(&path));
        }
    }
    let after = served(&setup, &name, &odometry[0]);
    answer_of(&mut before, &odometry[1]);
    drop((before, after));
    assert!(daemon.stop().unwrap());
}

/// A client with a `/tmp` of its own (systemd's `PrivateTmp=yes`, which many services have) is
/// served: it replays in a mount namespace with an empty `/tmp` and gets the answers a client
/// beside the daemon gets, byte for byte. Needs root (for the mount namespace) and `unshare`:
/// visibly skipped otherwise.
#[test]
fn a_client_with_a_private_tmp_is_served() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    if !root_with("a_client_with_a_private_tmp_is_served", &["unshare"]) {
        return;
    }
    let name = unique("private");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let dir = tempfile::tempdir_in(env!("CARGO_TARGET_TMPDIR")).unwrap();
    let input = dir.path().join("in.txt");
    let (_, odometry) = synthetic::drive(1, 3);
    write_kitti(&input, &odometry[..200]);
    // The checkout, and so the binary and these files, may lie in /tmp, which the private /tmp
    // hides: inside, the host's /tmp stays reachable at `view` (a folder outside /tmp).
    let view = tempfile::tempdir_in("/dev/shm").unwrap();
    let seen = |path: &std::path::Path, inside: bool| match path.strip_prefix("/tmp") {
        Ok(rest) if inside => view.path().join(rest).display().to_string(),
        _ => path.display().to_string(),
    };
    let replay_args = |out: &str, inside: bool| {
        vec![
            seen(
                std::path::Path::new(env!("CARGO_BIN_EXE_lanealign")),
                inside,
            ),
            "replay".into(),
            "--source".into(),
            name.clone(),
            "--namespace".into(),
            setup.namespace.clone(),
            seen(&input, inside),
            "-o".into(),
            seen(&dir.path().join(out), inside),
        ]
    };
    let beside = replay_args("beside.txt", false);
    let out = Command::new(&beside[0])
        .args(&beside[1..])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let out = Command::new("unshare")
        .args(["--mount", "--propagation", "private", "sh", "-c"])
        .arg(
            "mount --bind /tmp \"$0\" && mount -t tmpfs tmpfs /tmp && [ -z \"$(ls -A /tmp)\" ] \
             && exec \"$@\"",
        )
        .arg(view.path())
        .args(replay_args("private.txt", true))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let read_out = |f: &str| std::fs::read_to_string(dir.path().join(f)).unwrap();
    assert_eq!(read_out("private.txt").lines().count(), 200);
    assert_eq!(read_out("private.txt"), read_out("beside.txt"));
    assert!(daemon.stop().unwrap());
}

/// A full `/dev/shm` is an error, never a crash. iceoryx2 sizes its files with `ftruncate`,
/// which succeeds on a full tmpfs, and the first write to a page without room is a SIGBUS: a
/// client and a daemon died so before. The daemon runs in a mount namespace with a `/dev/shm`
/// of 8 MiB, its clients enter it (`nsenter`), and a filler file takes the room:
/// - 64 KiB left: the client says how much room there is and how much a session needs, and
///   exits with an error; the daemon is unharmed;
/// - a client that connected while there was room, and then the room is gone before the daemon
///   opens its session (the daemon stopped meanwhile): the daemon says it cannot answer the
///   session, once per metrics interval, counts the poses as `unserved`, starts no journal, and
///   goes on;
/// - the room back: a client is served, byte for byte as the first;
/// - a daemon starting in a `/dev/shm` of 16 to 48 KiB says there is no room for a source and
///   exits with an error (at 24 and 32 KiB it died of SIGBUS before).
///
/// Needs root (the mount namespace), `unshare`, `nsenter` and `fallocate`: visibly skipped
/// otherwise.
#[test]
fn a_full_shared_memory_is_an_error_not_a_crash() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    if !root_with(
        "a_full_shared_memory_is_an_error_not_a_crash",
        &["unshare", "nsenter", "fallocate"],
    ) {
        return;
    }
    let name = unique("full");
    let setup = town_setup(&[&name]);
    let log = setup.dir.path().join("daemon.log");
    let mut daemon = KillOnDrop(
        in_small_shm(&mut Command::new("unshare"), "8m", &setup)
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap(),
    );
    let daemon_log = || std::fs::read_to_string(&log).unwrap_or_default();
    let until = Instant::now() + Duration::from_secs(20);
    while !daemon_log().contains(" ready") {
        assert!(Instant::now() < until, "{}", daemon_log());
        std::thread::sleep(Duration::from_millis(10));
    }
    // Commands in the daemon's mount namespace.
    let inside = |args: &[&str]| {
        let mut c = Command::new("nsenter");
        c.arg(format!("--mount=/proc/{}/ns/mnt", daemon.0.id()))
            .arg("--")
            .args(args);
        c
    };
    let free = || -> u64 {
        let out = inside(&["stat", "-f", "-c", "%a %S", "/dev/shm"])
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&out.stdout).to_string();
        let v: Vec<u64> = text
            .split_whitespace()
            .map(|x| x.parse().unwrap())
            .collect();
        v[0] * v[1]
    };
    let fill_to = |left: u64| {
        let _ = inside(&["rm", "-f", "/dev/shm/filler"]).status();
        let size = free().saturating_sub(left).to_string();
        assert!(inside(&["fallocate", "-l", &size, "/dev/shm/filler"])
            .status()
            .unwrap()
            .success());
    };
    let dir = tempfile::tempdir_in(env!("CARGO_TARGET_TMPDIR")).unwrap();
    let input = dir.path().join("in.txt");
    let (_, odometry) = synthetic::drive(1, 5);
    write_kitti(&input, &odometry[..200]);
    let replay_in = |out: &str| {
        let output = dir.path().join(out);
        let mut c = inside(&[env!("CARGO_BIN_EXE_lanealign"), "replay", "--source", &name]);
        c.args(["--namespace", &setup.namespace, "--wait-for-daemon", "3"])
            .arg(&input)
            .arg("-o")
            .arg(&output);
        c
    };
    let read_out = |f: &str| std::fs::read_to_string(dir.path().join(f)).unwrap_or_default();

    let first = replay_in("first.txt").output().unwrap();
    assert!(first.status.success(), "{first:?}");
    assert_eq!(read_out("first.txt").lines().count(), 200);

    fill_to(64 << 10);
    let refused = replay_in("refused.txt").output().unwrap();
    let stderr = String::from_utf8_lossy(&refused.stderr).to_string();
    assert_eq!(refused.status.code(), Some(1), "{refused:?}");
    assert!(
        stderr.contains("/dev/shm has") && stderr.contains("a session needs up to 2600000"),
        "{stderr}"
    );

    // Room for the client, then none for the daemon's side.
    let _ = inside(&["rm", "-f", "/dev/shm/filler"]).status();
    signal(daemon.0.id(), Signal::STOP);
    let before = free();
    let unserved = replay_in("unserved.txt")
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let until = Instant::now() + Duration::from_secs(10);
    while free() > before - 500_000 {
        assert!(Instant::now() < until, "the client made no files");
        std::thread::sleep(Duration::from_millis(20));
    }
    fill_to(200 << 10);
    signal(daemon.0.id(), Signal::CONT);
    let out = unserved.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("not answered") && stderr.contains("the daemon never opened this session"),
        "{stderr}"
    );
    let unserved_poses = |text: &str| -> u64 {
        text.split("unserved=")
            .skip(1)
            .filter_map(|rest| rest.split_whitespace().next()?.parse::<u64>().ok())
            .sum()
    };
    let until = Instant::now() + Duration::from_secs(5);
    while unserved_poses(&daemon_log()) == 0 && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(50));
    }
    let text = daemon_log();
    assert!(unserved_poses(&text) > 0, "{text}");
    assert!(
        text.contains("cannot answer a session") && text.contains("/dev/shm has"),
        "{text}"
    );
    let warnings = text.matches("cannot answer a session").count();
    let intervals = text.matches("unserved=").count();
    assert!(
        warnings <= intervals,
        "{warnings} warnings in {intervals} intervals"
    );
    assert_eq!(
        journal_count(&setup, &name),
        0,
        "no journal for a session never served"
    );

    let _ = inside(&["rm", "-f", "/dev/shm/filler"]).status();
    let again = replay_in("again.txt").output().unwrap();
    assert!(again.status.success(), "{again:?}");
    assert_eq!(read_out("again.txt"), read_out("first.txt"));

    signal(daemon.0.id(), Signal::TERM);
    let status = daemon.0.wait().unwrap();
    assert!(status.success(), "{status:?}: {}", daemon_log());

    for size in ["16k", "24k", "32k", "48k"] {
        let out = in_small_shm(
            Command::new("timeout").args(["20", "unshare"]),
            size,
            &setup,
        )
        .output()
        .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{size}: {out:?}");
        assert!(
            stderr.contains("/dev/shm has") || stderr.contains("creating an iceoryx2 node"),
            "{size}: {stderr}"
        );
    }
}

/// `command` (`unshare`, or a wrapper of it) completed to run `lanealignd` on `setup`'s
/// configuration in a mount namespace of its own whose `/dev/shm` is a tmpfs of `size` (`8m`).
fn in_small_shm<'c>(command: &'c mut Command, size: &str, setup: &Setup) -> &'c mut Command {
    command
        .args(["--mount", "--propagation", "private", "sh", "-c"])
        .arg(format!(
            "mount -t tmpfs -o size={size} tmpfs /dev/shm && exec \"$0\" \"$@\""
        ))
        .arg(daemon_binary().unwrap())
        .arg("--config")
        .arg(&setup.config)
}

/// Always runs: a session's files stay within what the client and the daemon check for before
/// they make them (`lanealign_wire::shm`), and come near it (the bounds are the measured sizes
/// with a margin, not guesses). The daemon is stopped while the client connects, so that the
/// client's side is measured apart from the daemon's.
#[test]
fn a_session_needs_no_more_shared_memory_than_is_checked_for() {
    use lanealign_wire::shm::{CLIENT_SESSION_BYTES, DAEMON_SESSION_BYTES};
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("room");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let bytes = || -> u64 {
        let entries = namespace(&setup).entries();
        entries
            .iter()
            .filter(|(_, m)| m.is_file())
            .map(|(_, m)| m.len())
            .sum()
    };
    let alone = bytes();
    signal(daemon.id(), Signal::STOP);
    let mut client = connect(&setup, &name);
    let with_client = bytes();
    signal(daemon.id(), Signal::CONT);
    wait_for_daemon(&mut client);
    let (_, odometry) = synthetic::drive(1, 9);
    answer_of(&mut client, &odometry[0]);
    let served = bytes();
    let (client_side, daemon_side) = (with_client - alone, served - with_client);
    assert!(
        client_side <= CLIENT_SESSION_BYTES && client_side > CLIENT_SESSION_BYTES / 2,
        "client: {client_side} bytes"
    );
    assert!(
        daemon_side <= DAEMON_SESSION_BYTES && daemon_side > DAEMON_SESSION_BYTES / 2,
        "daemon: {daemon_side} bytes"
    );
    drop(client);
    assert!(daemon.stop().unwrap());
}

/// Always runs: a daemon out of file descriptors (its limit lowered to what it has open, with
/// `prlimit` from outside) goes on answering the session it serves, says once that it cannot
/// list nodes rather than every half second, says when it can again once the limit is back,
/// and then serves a new session.
#[test]
fn a_daemon_out_of_file_descriptors_says_so_once_and_recovers() {
    use rustix::process::{getrlimit, prlimit, Pid, Resource, Rlimit};
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("fds");
    let setup = town_setup(&[&name]);
    let daemon = start(&setup);
    let (_, odometry) = synthetic::drive(1, 11);
    let mut before = served(&setup, &name, &odometry[0]);
    let pid = Pid::from_raw(daemon.id() as i32).unwrap();
    let open = std::fs::read_dir(format!("/proc/{}/fd", daemon.id()))
        .unwrap()
        .count() as u64;
    let limit = getrlimit(Resource::Nofile);
    prlimit(
        Some(pid),
        Resource::Nofile,
        Rlimit {
            current: Some(open),
            maximum: limit.maximum,
        },
    )
    .unwrap();
    // Two seconds: four supervision periods.
    let until = Instant::now() + Duration::from_secs(2);
    let mut answered = 1;
    while Instant::now() < until {
        answer_of(&mut before, &odometry[answered]);
        answered += 1;
        std::thread::sleep(Duration::from_millis(50));
    }
    prlimit(Some(pid), Resource::Nofile, limit).unwrap();
    let until = Instant::now() + Duration::from_secs(5);
    while !daemon.log().contains("listing nodes works again") && Instant::now() < until {
        std::thread::sleep(Duration::from_millis(50));
    }
    let log = daemon.log();
    assert_eq!(log.matches("listing nodes failed").count(), 1, "{log}");
    assert!(log.contains("listing nodes works again"), "{log}");
    let after = served(&setup, &name, &odometry[0]);
    answer_of(&mut before, &odometry[answered]);
    drop((before, after));
    assert!(daemon.stop().unwrap());
}

/// `lanealignd` on `setup`'s configuration, its log (stderr) into `log`; killed when dropped.
fn daemon_logging_to(setup: &Setup, log: impl Into<Stdio>) -> KillOnDrop {
    KillOnDrop(
        Command::new(daemon_binary().unwrap())
            .arg("--config")
            .arg(&setup.config)
            .stderr(log)
            .spawn()
            .unwrap(),
    )
}

/// A child process killed when dropped: a failed assertion leaves no daemon running.
struct KillOnDrop(std::process::Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Always runs: a daemon and its clients leave nothing in shared memory behind them, in the
/// namespace's folder (`/dev/shm/lanealign-<namespace>/`) neither.
#[test]
fn nothing_is_left_in_shared_memory() {
    let _serial = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
    let name = unique("clean");
    let setup = town_setup(&[&name]);
    // iceoryx2 keeps per-namespace management state (created by the namespace's first node,
    // kept by design): create it before looking, so only what the processes leave counts.
    drop(
        namespace(&setup)
            .node::<lanealign_wire::service::Ipc>()
            .unwrap(),
    );
    let before = shm_entries();
    {
        let daemon = start(&setup);
        let (_, odometry) = synthetic::drive(1, 42);
        run_replay(&setup, &name, &odometry[..500], Rate::Max(32));
        let mut other =
            Connection::connect_in(&namespace(&setup), &name.parse().unwrap(), new_session_id())
                .unwrap();
        wait_for_daemon(&mut other);
        other.publish(0, &odometry[0].to_row_major()).unwrap();
        assert!(other.recv(Duration::from_secs(5)).unwrap().is_some());
        drop(other);
        assert!(daemon.stop().unwrap(), "clean exit on SIGTERM");
    }
    let after = shm_entries();
    // Shared memory, sockets and records count; the empty folders iceoryx2 keeps in the
    // namespace's folder (its `services/`) do not.
    let left: Vec<_> = after
        .difference(&before)
        .filter(|p| std::fs::read_dir(p).map_or(true, |mut d| d.next().is_some()))
        .collect();
    assert!(left.is_empty(), "left behind: {left:?}");
}
