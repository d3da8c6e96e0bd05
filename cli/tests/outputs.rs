//! `lanealign correct` writes its outputs together or not at all, and says when a run looks set
//! up wrongly.

use std::path::{Path, PathBuf};
use std::process::Command;

/// A lane CSV in `dir`: one lane along the x axis, `points` points 3 m apart.
fn straight_lane(dir: &Path, points: usize) -> PathBuf {
    let lanes = dir.join("lanes.csv");
    let mut text = String::from("lane_id,x,y\n");
    for i in 0..points {
        text.push_str(&format!("1,{},0\n", i as f64 * 3.0));
    }
    std::fs::write(&lanes, text).unwrap();
    lanes
}

/// `lanealign correct --preset kiss-icp --format tum --lanes LANES [SET] POSES` into `dir`: its
/// standard error and how many poses of its status file have `status`.
fn correct_tum(
    dir: &Path,
    lanes: &Path,
    poses: &Path,
    set: &[&str],
    status: &str,
) -> (String, usize) {
    let status_path = dir.join("status.csv");
    let out = Command::new(env!("CARGO_BIN_EXE_lanealign"))
        .args([
            "correct", "--preset", "kiss-icp", "--format", "tum", "--lanes",
        ])
        .arg(lanes)
        .args(set)
        .arg(poses)
        .arg("-o")
        .arg(dir.join("out.tum"))
        .arg("--status")
        .arg(&status_path)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{err}");
    let column = format!(",{status},");
    let count = std::fs::read_to_string(&status_path)
        .unwrap()
        .lines()
        .filter(|l| l.contains(&column))
        .count();
    (err, count)
}

/// `poses` TUM poses at `rate_hz` along the lane of [`straight_lane`] at 10 m/s, 0.5 m beside
/// it, written to `poses.tum` in `dir`, their stamps `stamp_scale` times the seconds they
/// come at (1 for stamps in seconds).
fn tum_along_the_lane(dir: &Path, poses: usize, rate_hz: f64, stamp_scale: f64) -> PathBuf {
    let path = dir.join("poses.tum");
    let lines: String = (0..poses)
        .map(|i| {
            let t = i as f64 / rate_hz;
            format!("{} {} 0.5 0 0 0 0 1\n", 1.7e9 + stamp_scale * t, 10.0 * t)
        })
        .collect();
    std::fs::write(&path, lines).unwrap();
    path
}

#[test]
fn outputs_appear_only_when_the_whole_run_succeeded() {
    let dir = tempfile::tempdir().unwrap();
    let lanes = straight_lane(dir.path(), 100);
    let poses = dir.path().join("poses.txt");
    let lines: String = (0..300)
        .map(|i| format!("1 0 0 {i} 0 1 0 500 0 0 1 0\n"))
        .collect();
    std::fs::write(&poses, lines).unwrap();
    let out = dir.path().join("out.txt");
    let run = |status: &Path| {
        Command::new(env!("CARGO_BIN_EXE_lanealign"))
            .args(["correct", "--preset", "kiss-icp", "--lanes"])
            .arg(&lanes)
            .arg(&poses)
            .arg("-o")
            .arg(&out)
            .arg("--status")
            .arg(status)
            .output()
            .unwrap()
    };
    let failed = run(&dir.path().join("missing/status.csv"));
    assert_eq!(failed.status.code(), Some(1));
    assert!(
        !out.exists(),
        "-o must not appear when --status cannot be written"
    );
    let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(left.len(), 2, "no partial files are left");
    let ok = run(&dir.path().join("status.csv"));
    let err = String::from_utf8_lossy(&ok.stderr);
    assert!(ok.status.success(), "{err}");
    assert!(out.exists() && dir.path().join("status.csv").exists());
    // 500 m beside the only lane: nothing can be accepted, and the run says so.
    assert!(
        err.contains("WARN no correction was accepted in ")
            && err.contains(" attempts over 300 poses")
            && err.contains(
                "check the anchor (YAW_DEG in degrees from East, counter-clockwise), --frame"
            ),
        "{err}"
    );
}

#[test]
fn a_tum_source_faster_than_its_preset_is_told_the_setting() {
    let dir = tempfile::tempdir().unwrap();
    let lanes = straight_lane(dir.path(), 200);
    let poses = tum_along_the_lane(dir.path(), 2000, 100.0, 1.0);
    let run = |set: &[&str]| correct_tum(dir.path(), &lanes, &poses, set, "carried");
    // An alignment on every window pose and no standstill (the robust method's spacing of 1 m
    // would carry poses 0.1 m apart too, and its standstill of 1 m/s, taken at the presets'
    // 10 Hz, those that came a rounding closer than 0.1 m), so that the count is the stride's.
    let every_pose = [
        "--set",
        "alignment_spacing_m=0",
        "--set",
        "standstill_speed_mps=0",
    ];
    let (err, carried) = run(&every_pose);
    assert!(
        err.contains("WARN the poses come at about 100 Hz")
            && err.contains("--set odometry_rate_hz=100"),
        "{err}"
    );
    assert_eq!(carried, 0);
    let (err, carried) = run(&[&every_pose[..], &["--set", "odometry_rate_hz=100"]].concat());
    assert!(!err.contains("Hz (their stamps)"), "{err}");
    assert_eq!(carried, 1800, "nine of every ten poses");
}

/// A TUM file whose stamps are 1000 times too close (a 10 Hz source driving 10 m/s, stamped 0.1
/// ms apart: microseconds read as nanoseconds on the wire read so): the run asks about the
/// stamps' unit instead of naming a rate of 10 kHz to set, and judges the speed at the rate the
/// corrector is set for, so it does not call the odometry 1000 times too fast (until 2026-12-02
/// it said "set odometry_rate_hz = 10000" and "the odometry moves at 10000 m/s").
#[test]
fn stamps_too_close_for_any_odometry_are_asked_about() {
    let dir = tempfile::tempdir().unwrap();
    let lanes = straight_lane(dir.path(), 200);
    let poses = tum_along_the_lane(dir.path(), 1000, 10.0, 1e-3);
    let (err, _) = correct_tum(dir.path(), &lanes, &poses, &[], "accepted");
    let warnings: Vec<&str> = err.lines().filter(|l| l.starts_with("WARN")).collect();
    assert_eq!(warnings.len(), 1, "{err}");
    assert!(
        warnings[0].contains("the poses' stamps are 100 us apart (the median)")
            && warnings[0].contains("Microseconds sent as nanoseconds"),
        "{err}"
    );
}

/// A TUM file whose quaternions were written scalar first (`qw qx qy qz`, the order of Eigen's
/// constructor) reads as a vehicle upside down: the run says so, and its corrections are
/// those of the file written in TUM's order.
#[test]
fn quaternions_written_scalar_first_are_told() {
    let dir = tempfile::tempdir().unwrap();
    let lanes = straight_lane(dir.path(), 200);
    let poses = tum_along_the_lane(dir.path(), 1000, 10.0, 1.0);
    let (err, accepted) = correct_tum(dir.path(), &lanes, &poses, &[], "accepted");
    assert!(!err.contains("WARN"), "{err}");
    let in_order = std::fs::read_to_string(dir.path().join("out.tum")).unwrap();
    let text = std::fs::read_to_string(&poses).unwrap();
    let scalar_first: String = text
        .lines()
        .map(|l| l.replace(" 0 0 0 1", " 1 0 0 0") + "\n")
        .collect();
    std::fs::write(&poses, scalar_first).unwrap();
    let (err, accepted_scalar_first) = correct_tum(dir.path(), &lanes, &poses, &[], "accepted");
    assert!(
        err.contains(
            "WARN the poses are tilted more than 60 degrees from upright on 100% of their path"
        ) && err.contains("were these written qw qx qy qz?"),
        "{err}"
    );
    assert!(
        accepted > 600 && accepted_scalar_first == accepted,
        "{accepted} {accepted_scalar_first}"
    );
    let positions = |text: &str| -> Vec<String> {
        text.lines()
            .map(|l| l.split(' ').take(4).collect::<Vec<_>>().join(" "))
            .collect()
    };
    let out = std::fs::read_to_string(dir.path().join("out.tum")).unwrap();
    assert_eq!(positions(&out), positions(&in_order));
}

/// A restarted odometry is told as a jump; the same drive paused for 3 s is told as poses
/// missing without stamps, and not at all with stamps that time the pause.
#[test]
fn an_odometry_that_jumps_is_told_where_and_a_paused_one_is_not() {
    let dir = tempfile::tempdir().unwrap();
    let lanes = straight_lane(dir.path(), 200);
    // Along the lane at 12 m/s (10 Hz), 0.5 m beside it; the odometry restarts at its origin at
    // pose 300. As TUM: the same, with a 3 s pause before pose 300 instead; and the paused drive
    // without stamps.
    let kitti = dir.path().join("restarted.txt");
    let lines: String = (0..400)
        .map(|i| {
            let x = if i < 300 { i } else { i - 300 } as f64 * 1.2;
            format!("1 0 0 {x} 0 1 0 0.5 0 0 1 0\n")
        })
        .collect();
    std::fs::write(&kitti, lines).unwrap();
    let tum = dir.path().join("paused.tum");
    let lines: String = (0..400)
        .map(|i| {
            let t = i as f64 * 0.1 + if i < 300 { 0.0 } else { 3.0 };
            let x = if i < 300 { i } else { i + 30 } as f64 * 1.2;
            format!("{t} {x} 0.5 0 0 0 0 1\n")
        })
        .collect();
    std::fs::write(&tum, lines).unwrap();
    let gap = dir.path().join("paused.txt");
    let lines: String = (0..400)
        .map(|i| {
            let x = if i < 300 { i } else { i + 30 } as f64 * 1.2;
            format!("1 0 0 {x} 0 1 0 0.5 0 0 1 0\n")
        })
        .collect();
    std::fs::write(&gap, lines).unwrap();
    let run = |poses: &Path, format: &str| {
        let out = Command::new(env!("CARGO_BIN_EXE_lanealign"))
            .args([
                "correct", "--preset", "kiss-icp", "--format", format, "--lanes",
            ])
            .arg(&lanes)
            .arg(poses)
            .arg("-o")
            .arg(dir.path().join(format!("out.{format}")))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(out.status.success(), "{err}");
        err
    };
    let err = run(&kitti, "kitti");
    assert!(
        err.contains(
            "WARN the odometry jumped at 1 pose (300): farther than max_speed_mps (70 m/s)"
        ),
        "{err}"
    );
    assert!(!err.contains("poses missing"), "{err}");
    let err = run(&tum, "tum");
    assert!(!err.contains("jumped"), "{err}");
    assert!(!err.contains("poses missing"), "{err}");
    let err = run(&gap, "kitti");
    assert!(!err.contains("jumped"), "{err}");
    assert!(
        err.contains(
            "WARN 1 step of the odometry (300) was longer than max_speed_mps (70 m/s) allows in \
             one period at odometry_rate_hz (10 Hz) and drove on as the step before: taken for \
             poses missing from the input"
        ),
        "{err}"
    );
}

/// Along a lane at 20 m/s (10 Hz), the odometry falls to 1 m/s within a step at pose 200, as a
/// visual odometry that loses track does: `correct` says where, and that no car slows so fast.
/// The same drive braking at 8 m/s^2, as a car can, is not told.
#[test]
fn an_odometry_that_stalls_is_told_where() {
    let dir = tempfile::tempdir().unwrap();
    let lanes = straight_lane(dir.path(), 400);
    let run = |name: &str, speed: &dyn Fn(usize) -> f64| {
        let poses = dir.path().join(name);
        let mut x = 0.0;
        let lines: String = (0..400)
            .map(|i| {
                let line = format!("1 0 0 {x} 0 1 0 0.5 0 0 1 0\n");
                x += speed(i) / 10.0;
                line
            })
            .collect();
        std::fs::write(&poses, lines).unwrap();
        let out = Command::new(env!("CARGO_BIN_EXE_lanealign"))
            .args(["correct", "--preset", "kiss-icp", "--lanes"])
            .arg(&lanes)
            .arg(&poses)
            .arg("-o")
            .arg(dir.path().join("out.txt"))
            .arg("--results")
            .arg(dir.path().join("results"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(out.status.success(), "{err}");
        // The results folder keeps the WARN lines, one a line.
        let kept = std::fs::read_to_string(dir.path().join("results/latest/warnings.txt")).unwrap();
        let told: Vec<&str> = err
            .lines()
            .filter_map(|l| l.strip_prefix("WARN "))
            .collect();
        assert_eq!(kept.lines().collect::<Vec<_>>(), told);
        err
    };
    let err = run("stalled.txt", &|i| if i < 200 { 20.0 } else { 1.0 });
    assert!(
        err.contains(
            "WARN the odometry's speed changes faster than a car's can (more than 10 m/s^2 over \
             0.5 s) at 1 place: pose 200 (20.0 -> 1.0 m/s)"
        ),
        "{err}"
    );
    let err = run("braking.txt", &|i| {
        (20.0 - 0.8 * i.saturating_sub(200) as f64).max(0.0)
    });
    assert!(!err.contains("faster than a car"), "{err}");
    let kept = std::fs::read_to_string(dir.path().join("results/latest/warnings.txt")).unwrap();
    assert_eq!(kept, "", "no warning, an empty file");
}

/// A TUM source at 2 Hz is told to set its rate; set, it is corrected without the warning, and
/// its first alignment comes after a fifth of the presets' 150 poses.
#[test]
fn a_tum_source_slower_than_its_preset_is_told_the_setting() {
    let dir = tempfile::tempdir().unwrap();
    let lanes = straight_lane(dir.path(), 200);
    let poses = tum_along_the_lane(dir.path(), 100, 2.0, 1.0);
    let run = |set: &[&str]| correct_tum(dir.path(), &lanes, &poses, set, "warming_up");
    let (err, warming) = run(&[]);
    assert!(
        err.contains("WARN the poses come at about 2.0 Hz")
            && err.contains("--set odometry_rate_hz=2.0"),
        "{err}"
    );
    assert_eq!(warming, 100, "150 poses are more than the run has");
    let (err, warming) = run(&["--set", "odometry_rate_hz=2.0"]);
    assert!(!err.contains("Hz (their stamps)"), "{err}");
    assert_eq!(warming, 29, "a window of 30 poses");
}

/// `lanealign params` shows the pose counts the corrector uses at the source's rate: a stride
/// above 10 Hz, the counts scaled down below it.
#[test]
fn params_show_the_pose_counts_at_the_sources_rate() {
    let at_rate = |hz: &str| {
        let out = Command::new(env!("CARGO_BIN_EXE_lanealign"))
            .args(["params", "--preset", "kiss-icp", "--set"])
            .arg(format!("odometry_rate_hz={hz}"))
            .output()
            .unwrap();
        assert!(out.status.success(), "{out:?}");
        let printed: toml::Table = String::from_utf8(out.stdout).unwrap().parse().unwrap();
        let counts = &printed["at_rate"];
        ["window_stride", "min_window", "max_window", "max_failures"]
            .map(|key| counts[key].as_integer().unwrap())
    };
    assert_eq!(at_rate("10"), [1, 150, 1000, 1000]);
    assert_eq!(at_rate("100"), [10, 150, 1000, 1000]);
    assert_eq!(at_rate("2"), [1, 30, 200, 200]);
}

/// `lanealign eval ... | head -1`: a reader that goes away ends the command as it ends Unix
/// filters (SIGPIPE), not with a panic on stderr.
#[test]
fn a_closed_stdout_ends_a_command_quietly() {
    use std::os::unix::process::ExitStatusExt;
    let (reader, writer) = std::io::pipe().unwrap();
    drop(reader);
    let out = Command::new(env!("CARGO_BIN_EXE_lanealign"))
        .args(["params", "--preset", "kiss-icp"])
        .stdout(writer)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(
        out.status.signal(),
        Some(rustix::process::Signal::PIPE.as_raw()),
        "{:?}: {err}",
        out.status
    );
    assert!(err.is_empty(), "{err}");
}
