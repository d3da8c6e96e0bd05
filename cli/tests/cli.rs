//! The `lanealign` command line: evaluation against evo, bad input, and the version lines.

use std::path::Path;
use std::process::{Command, Output};

use lanealign_tests::shared_data;

fn lanealign(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_lanealign"))
        .args(args)
        .output()
        .expect("run lanealign")
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// A lane CSV in `dir`: one eastbound lane along y = 0, 300 m long.
fn straight_lane(dir: &Path) -> std::path::PathBuf {
    let lanes = dir.join("lanes.csv");
    let lane: String = (0..100)
        .map(|i| format!("1,{},0\n", i as f64 * 3.0))
        .collect();
    std::fs::write(&lanes, format!("lane_id,x,y\n{lane}")).unwrap();
    lanes
}

/// `lanealign eval --json` of `est` against `gt` (KITTI format, camera axes); panics on failure.
fn eval_json(gt: &Path, est: &Path) -> serde_json::Value {
    let out = lanealign(&[
        "eval",
        "--gt",
        s(gt),
        "--est",
        s(est),
        "--frame",
        "kitti-camera",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("json")
}

/// `evo_ape kitti GT EST --project_to_plane xy` (evo 1.x, no alignment) on KITTI 00, the lidar
/// odometry against ground truth, both rotated from the camera frame into the planar frame:
/// mean 4.008812199526548, rmse 4.968945055378295, max 14.595055131424358.
#[test]
fn eval_equals_evo_on_kitti_00() {
    let Some(d) = shared_data() else { return };
    let v = eval_json(
        &d.join("kitti/poses/00.txt"),
        &d.join("odometry/lidar/00.txt"),
    );
    let get = |k: &str| v[k].as_f64().unwrap_or(f64::NAN);
    assert!(
        (get("ape2d_mean_m") - 4.008812199526548).abs() < 1e-6,
        "{v}"
    );
    assert!((get("rmse_m") - 4.968945055378295).abs() < 1e-6, "{v}");
    assert_eq!(v["poses"].as_u64(), Some(4541));
    for key in ["lateral_rmse_m", "heading_mean_deg"] {
        assert!(get(key).is_finite(), "{key} in {v}");
    }
}

/// Paired by time, `eval` says how many of the estimate's poses it left out, names where both
/// files' stamps lie when none pair, and takes evo's `--t_max_diff` and `--t_offset` as
/// `--max-dt` and `--t-offset`: an estimate 0.5 m beside the truth whose clock runs 60 ms late,
/// 300 poses against 200 of ground truth.
#[test]
fn eval_pairs_stamps_as_told_and_says_what_it_left_out() {
    let dir = tempfile::tempdir().unwrap();
    let tum = |name: &str, poses: usize, late_s: f64, y: f64| {
        let path = dir.path().join(name);
        let lines: String = (0..poses)
            .map(|i| format!("{} {i} {y} 0 0 0 0 1\n", 1000.0 + 0.1 * i as f64 + late_s))
            .collect();
        std::fs::write(&path, lines).unwrap();
        path
    };
    let (gt, est) = (tum("gt.tum", 200, 0.0, 0.0), tum("est.tum", 300, 0.06, 0.5));
    let eval = |extra: &[&str]| {
        let base = [
            "eval",
            "--format",
            "tum",
            "--json",
            "--gt",
            s(&gt),
            "--est",
            s(&est),
        ];
        let out = lanealign(&[&base[..], extra].concat());
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_default();
        (out.status.code(), json, err)
    };
    let (code, _, err) = eval(&[]);
    assert_eq!(code, Some(1));
    assert!(
        err.contains(
            "no estimate stamp lies within 0.01 s of a ground-truth stamp: the ground truth's 200 \
             stamps run from 1000.000 to 1019.900 s, the estimate's 300 stamps run from 1000.060 \
             to 1029.960 s"
        ) && err.contains("--t-offset shifts the estimate's stamps"),
        "{err}"
    );
    let (code, json, err) = eval(&["--t-offset", "-0.06"]);
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(json["poses"], 200, "{json}");
    assert!(
        (json["ape2d_mean_m"].as_f64().unwrap_or(f64::NAN) - 0.5).abs() < 1e-9,
        "{json}"
    );
    assert!(
        err.contains(
            "200 of the estimate's 300 poses paired with a ground-truth pose within 0.01 s"
        ),
        "{err}"
    );
    // Wide enough for the late clock, each estimated pose pairs with the truth 40 ms after it.
    let (code, json, _) = eval(&["--max-dt", "0.05"]);
    assert_eq!(code, Some(0));
    assert_eq!(json["poses"], 199, "{json}");
    assert!(
        (json["ape2d_mean_m"].as_f64().unwrap_or(f64::NAN) - 1.25f64.sqrt()).abs() < 1e-9,
        "{json}"
    );
    for bad in ["0", "-1", "nan", "inf", "3601"] {
        let (code, _, err) = eval(&["--max-dt", bad]);
        assert_eq!(code, Some(2), "--max-dt {bad}: {err}");
    }
    let kitti = lanealign(&["eval", "--gt", s(&gt), "--est", s(&gt), "--max-dt", "0.1"]);
    assert!(
        String::from_utf8_lossy(&kitti.stderr).contains("only with --format tum"),
        "{kitti:?}"
    );
}

/// Where `kitti/georef.csv` places KITTI 00's odometry frame (`--anchor`).
const ANCHOR_00: &str = "48.9825452359,8.3903661,59.5584,0.806,0.365";

/// The `WARN` lines of `lanealign correct` of `odometry` (KITTI 00, camera axes, the kiss-icp
/// preset) against KITTI 00's OSM placed by `anchor`, which must succeed; its output goes to
/// `dir`.
fn warnings_correcting_00(d: &Path, odometry: &Path, anchor: &str, dir: &Path) -> Vec<String> {
    let out = lanealign(&[
        "correct",
        "--osm",
        s(&d.join("osm/kitti_00.osm")),
        "--anchor",
        anchor,
        "--projection",
        "kitti",
        "--preset",
        "kiss-icp",
        "--frame",
        "kitti-camera",
        s(odometry),
        "-o",
        s(&dir.join("out.txt")),
    ]);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{err}");
    let warnings = err.lines().filter(|l| l.starts_with("WARN "));
    warnings.map(str::to_string).collect()
}

/// An anchor given wrongly, so that a few alignments are accepted but not the rest, is told: on
/// KITTI 00's LiDAR run its yaw in radians, of the other sign, measured clockwise from North, or
/// the anchor 50 m east (0.5-7.4 % accepted, against 100 % with the right anchor and at least
/// 26 % on every shared run). Each exited 0 without a word before.
#[test]
fn an_anchor_given_wrongly_is_told() {
    let Some(d) = shared_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let odometry = d.join("odometry/lidar/00.txt");
    let warned = |anchor: &str| warnings_correcting_00(&d, &odometry, anchor, dir.path());
    assert_eq!(warned(ANCHOR_00), Vec::<String>::new());
    for (yaw_east_north, accepted) in [
        ("1.0395,0.806,0.365", "only 40 of 4332 alignments"),
        ("-59.5584,0.806,0.365", "only 20 of 4371 alignments"),
        ("30.4416,0.806,0.365", "only 40 of 4335 alignments"),
        ("59.5584,50.806,0.365", "only 314 of 4259 alignments"),
    ] {
        let warnings = warned(&format!("48.9825452359,8.3903661,{yaw_east_north}"));
        assert_eq!(warnings.len(), 1, "{yaw_east_north}: {warnings:?}");
        assert!(
            warnings[0].contains(accepted)
                && warnings[0].contains("YAW_DEG in degrees from East, counter-clockwise"),
            "{yaw_east_north}: {warnings:?}"
        );
    }
}

/// An odometry whose positions are not in metres is told: KITTI 00's LiDAR run in centimetres
/// moves at 849 m/s (none of its alignments is accepted), in feet 24 of 3348 alignments are
/// accepted; both exited 0 with at most a list of speed changes before.
#[test]
fn an_odometry_in_other_units_is_told() {
    let Some(d) = shared_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let metres = std::fs::read_to_string(d.join("odometry/lidar/00.txt")).unwrap();
    let warned = |per_metre: f64| {
        let scaled: String = metres
            .lines()
            .map(|line| {
                let row: Vec<String> = line
                    .split_whitespace()
                    .enumerate()
                    .map(|(i, v)| {
                        let v: f64 = v.parse().unwrap();
                        (if i % 4 == 3 { v * per_metre } else { v }).to_string()
                    })
                    .collect();
                row.join(" ") + "\n"
            })
            .collect();
        let input = dir.path().join("scaled.txt");
        std::fs::write(&input, scaled).unwrap();
        warnings_correcting_00(&d, &input, ANCHOR_00, dir.path())
    };
    assert_eq!(warned(1.0), Vec::<String>::new());
    let centimetres = warned(100.0);
    assert_eq!(centimetres.len(), 2, "{centimetres:?}");
    assert!(centimetres[0].contains("no correction was accepted in 209 attempts"));
    assert!(
        centimetres[1].starts_with("WARN the odometry moves at 849 m/s")
            && centimetres[1].contains("are its positions in metres"),
        "{centimetres:?}"
    );
    let feet = warned(3.28084);
    assert!(
        feet[0].contains("only 24 of 3348 alignments")
            && feet[0].contains("that the poses are in metres"),
        "{feet:?}"
    );
}

/// `--method paper` keeps the corrector issue's figures (docs/results.md, KITTI 00, lidar,
/// kiss-icp, OSM lanes): APE-2D 1.660 m after 4392 match attempts, 3384 accepted, 0 resets; the
/// default (robust) method does better on the same input.
#[test]
fn method_paper_keeps_the_published_figures_on_kitti_00() {
    let Some(d) = shared_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let mean_of = |method: &str| {
        let output = dir.path().join(format!("{method}.txt"));
        let out = lanealign(&[
            "correct",
            "--osm",
            s(&d.join("osm/kitti_00.osm")),
            "--anchor",
            "48.9825452359,8.3903661000,59.5584,0.806,0.365",
            "--projection",
            "kitti",
            "--preset",
            "kiss-icp",
            "--frame",
            "kitti-camera",
            "--method",
            method,
            s(&d.join("odometry/lidar/00.txt")),
            "-o",
            s(&output),
        ]);
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(out.status.success(), "{err}");
        let v = eval_json(&d.join("kitti/poses/00.txt"), &output);
        (v["ape2d_mean_m"].as_f64().unwrap_or(f64::NAN), err)
    };
    let (paper, err) = mean_of("paper");
    assert!((paper - 1.6601894661160674).abs() < 1e-9, "paper: {paper}");
    assert!(
        err.contains("method paper: 4392 match attempts, 3384 accepted, 0 resets"),
        "{err}"
    );
    let (robust, _) = mean_of("robust");
    assert!(robust < paper - 0.1, "robust {robust} vs paper {paper}");
}

const LANES: &str = "lane_id,x,y\n1,0,0\n1,3,0\n1,6,0\n1,9,0\n1,12,0\n";

#[test]
fn bad_pose_lines_name_file_and_line_and_fail() {
    let dir = tempfile::tempdir().unwrap();
    let lanes = dir.path().join("lanes.csv");
    std::fs::write(&lanes, LANES).unwrap();
    let good = "1 0 0 0 0 1 0 0 0 0 1 0\n";
    let cases = [
        (
            "short.txt",
            format!("{good}1 0 0 0 0 1 0\n"),
            ":2:",
            "expected 12 numbers",
        ),
        (
            "word.txt",
            format!("{good}{good}1 0 0 zero 0 1 0 0 0 0 1 0\n"),
            ":3:",
            "not a number",
        ),
        (
            "nan.txt",
            "1 0 0 NaN 0 1 0 0 0 0 1 0\n".to_string(),
            ":1:",
            "not finite",
        ),
        (
            "inf.txt",
            format!("{good}1 0 0 inf 0 1 0 0 0 0 1 0\n"),
            ":2:",
            "not finite",
        ),
    ];
    for (name, text, line, what) in cases {
        let input = dir.path().join(name);
        std::fs::write(&input, text).unwrap();
        let output = dir.path().join("out.txt");
        let out = lanealign(&[
            "correct",
            "--lanes",
            s(&lanes),
            "--preset",
            "kiss-icp",
            s(&input),
            "-o",
            s(&output),
        ]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{name} must fail");
        assert!(
            err.contains(&format!("{name}{line}")) && err.contains(what),
            "{name}: {err}"
        );
        assert!(!output.exists(), "no output for bad input");
    }
}

/// `lanealign ARGS` exits with 1 and says `says`.
fn assert_refused(args: &[&str], says: &str) {
    let out = lanealign(args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{args:?}: {err}");
    assert!(err.contains(says), "{args:?}: {err}");
}

/// An output that names an input (the same path, a link to it, a hard link) is refused before
/// anything is read or written, and the input is left as it was: every output replaces its file
/// whole. `replay` refuses before looking for a daemon.
#[test]
fn an_output_that_is_an_input_is_refused_and_the_input_kept() {
    let dir = tempfile::tempdir().unwrap();
    let lanes = straight_lane(dir.path());
    let run = dir.path().join("run.txt");
    let poses: String = (0..50)
        .map(|i| format!("1 0 0 {} 0 1 0 0.5 0 0 1 0\n", i as f64 * 1.2))
        .collect();
    std::fs::write(&run, &poses).unwrap();
    let hard = dir.path().join("hard.txt");
    std::fs::hard_link(&run, &hard).unwrap();
    let link = dir.path().join("link.csv");
    std::os::unix::fs::symlink(&lanes, &link).unwrap();
    let lanes_text = std::fs::read_to_string(&lanes).unwrap();
    let new = dir.path().join("new.txt");
    let (run, hard, lanes, link, new_path) = (s(&run), s(&hard), s(&lanes), s(&link), s(&new));
    let correct = ["correct", "--lanes", lanes, "--preset", "kiss-icp", run];
    let cases: Vec<Vec<&str>> = vec![
        [&correct[..], &["-o", run]].concat(),
        [&correct[..], &["-o", hard]].concat(),
        [&correct[..], &["-o", new_path, "--status", link]].concat(),
        vec!["eval", "--gt", run, "--est", run, "--plot", hard],
        vec!["replay", "--source", "lidar", run, "-o", run],
    ];
    for args in cases {
        assert_refused(&args, "is the input");
    }
    assert_eq!(std::fs::read_to_string(run).unwrap(), poses);
    assert_eq!(std::fs::read_to_string(lanes).unwrap(), lanes_text);
    assert!(!new.exists(), "nothing written");
}

/// `-o` and `--status` naming one file (it failed, and left the status CSV where the trajectory
/// was to be) and a `--results` that names a file are refused, and nothing is written.
#[test]
fn outputs_that_cannot_all_be_written_are_refused_and_none_is_written() {
    let dir = tempfile::tempdir().unwrap();
    let lanes = straight_lane(dir.path());
    let run = dir.path().join("run.txt");
    std::fs::write(&run, "1 0 0 0 0 1 0 0.5 0 0 1 0\n".repeat(20)).unwrap();
    let out = dir.path().join("out.txt");
    let dotted = dir.path().join(".").join("out.txt");
    let file = dir.path().join("results");
    std::fs::write(&file, "").unwrap();
    let correct = [
        "correct",
        "--lanes",
        s(&lanes),
        "--preset",
        "kiss-icp",
        s(&run),
    ];
    for (extra, says) in [
        (
            ["-o", s(&out), "--status", s(&dotted)],
            "named for two outputs",
        ),
        (["-o", s(&out), "--results", s(&file)], "not a folder"),
    ] {
        let args = [&correct[..], &extra[..]].concat();
        assert_refused(&args, says);
        assert!(!out.exists(), "{args:?}: nothing written");
    }
}

#[test]
fn bad_osm_is_a_clear_error_and_missing_nodes_are_counted() {
    let dir = tempfile::tempdir().unwrap();
    let poses = dir.path().join("poses.txt");
    let line = |x: f64| format!("1 0 0 {x} 0 1 0 0 0 0 1 0\n");
    std::fs::write(&poses, (0..20).map(|i| line(i as f64)).collect::<String>()).unwrap();
    let anchor = "49.0,8.4,0";
    let output = dir.path().join("o.txt");
    let correct_with = |osm: &Path| {
        lanealign(&[
            "correct",
            "--osm",
            s(osm),
            "--anchor",
            anchor,
            "--preset",
            "kiss-icp",
            s(&poses),
            "-o",
            s(&output),
        ])
    };
    let not_xml = dir.path().join("not.osm");
    std::fs::write(&not_xml, "PK\u{3}\u{4} this is a zip, not OSM").unwrap();
    let out = correct_with(&not_xml);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("not.osm") && err.contains("not an OSM XML file"),
        "{err}"
    );

    // Lanes derived at a spacing of 1e300 m were one point each, and the run went uncorrected
    // with only a warning.
    let road = dir.path().join("road.osm");
    std::fs::write(
        &road,
        r#"<osm><node id="1" lat="49.0" lon="8.4"/><node id="2" lat="49.0" lon="8.401"/>
        <way id="3"><nd ref="1"/><nd ref="2"/><tag k="highway" v="primary"/></way></osm>"#,
    )
    .unwrap();
    for spacing in ["0", "NaN", "10.5", "1e300"] {
        let out = lanealign(&[
            "correct",
            "--osm",
            s(&road),
            "--anchor",
            anchor,
            "--preset",
            "kiss-icp",
            &format!("--spacing={spacing}"),
            s(&poses),
            "-o",
            s(&output),
        ]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{spacing}: {err}");
        assert!(
            err.contains("--spacing: the lane point spacing")
                && err.contains("m is outside (0, 10] m"),
            "{spacing}: {err}"
        );
        assert!(!output.exists());
    }

    let missing = dir.path().join("missing.osm");
    std::fs::write(
        &missing,
        r#"<osm><node id="1" lat="49.0" lon="8.4"/><node id="2" lat="49.0" lon="8.401"/>
        <way id="3"><nd ref="1"/><nd ref="2"/><nd ref="404"/><tag k="highway" v="primary"/></way></osm>"#,
    )
    .unwrap();
    let out = correct_with(&missing);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("1 node references missing"), "{err}");
}

#[test]
fn correct_writes_every_pose_and_a_status_row_each() {
    let dir = tempfile::tempdir().unwrap();
    let lanes = straight_lane(dir.path());
    // TUM input drifted 0.8 m left of the lane (within the robust method's 1 m tolerance band,
    // so the paper's method, which pulls onto the line).
    let tum: String = (0..200)
        .map(|i| format!("{} {} 0.8 0 0 0 0 1\n", i as f64 * 0.1, i as f64 * 1.2))
        .collect();
    let input = dir.path().join("in.tum");
    std::fs::write(&input, tum).unwrap();
    let output = dir.path().join("out.tum");
    let status = dir.path().join("status.csv");
    let out = lanealign(&[
        "correct",
        "--lanes",
        s(&lanes),
        "--preset",
        "kiss-icp",
        "--format",
        "tum",
        "--method",
        "paper",
        "--set",
        "min_window=20",
        s(&input),
        "-o",
        s(&output),
        "--status",
        s(&status),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let corrected = std::fs::read_to_string(&output).unwrap();
    assert_eq!(corrected.lines().count(), 200);
    let last: Vec<f64> = corrected
        .lines()
        .last()
        .unwrap()
        .split(' ')
        .map(|v| v.parse().unwrap())
        .collect();
    assert!(last[2].abs() < 1e-6, "the drift is removed: {last:?}");
    let rows = std::fs::read_to_string(&status).unwrap();
    assert_eq!(rows.lines().count(), 201);
    assert!(rows.lines().nth(19).unwrap().contains(",warming_up,"));
    assert!(rows.lines().last().unwrap().contains(",accepted,"));
}

/// `correct --status` publishes a covariance per pose and `eval --status` measures it: on
/// `stereo_vo` 09 (orb-slam3 preset) 94 % of the true errors lie inside the 95 % ellipses, and
/// how many independent samples that figure rests on, what an exact covariance would show over
/// as many and the verdict (docs/method.md, "Confidence").
#[test]
fn eval_reports_how_well_the_covariance_describes_the_errors() {
    let Some(d) = shared_data() else { return };
    let dir = tempfile::tempdir().unwrap();
    let (output, status) = (dir.path().join("09.txt"), dir.path().join("09.csv"));
    let out = lanealign(&[
        "correct",
        "--osm",
        s(&d.join("osm/kitti_09.osm")),
        "--anchor",
        "48.9721045445,8.4761469953,-27.5197,0.539,-0.887",
        "--projection",
        "kitti",
        "--preset",
        "orb-slam3",
        "--frame",
        "kitti-camera",
        s(&d.join("odometry/stereo_vo/09.txt")),
        "-o",
        s(&output),
        "--status",
        s(&status),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let eval = |status: &Path| {
        lanealign(&[
            "eval",
            "--gt",
            s(&d.join("kitti/poses/09.txt")),
            "--est",
            s(&output),
            "--frame",
            "kitti-camera",
            "--status",
            s(status),
            "--json",
        ])
    };
    let out = eval(&status);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    let coverage = v["cov95_coverage"].as_f64().unwrap();
    let nees = v["nees_mean"].as_f64().unwrap();
    assert!((0.85..=0.99).contains(&coverage), "{v}");
    assert!((1.0..4.0).contains(&nees), "{v}");
    // The errors persist over about 450 poses: the drive's 1591 are some four independent ones.
    let independent = v["independent_samples"].as_f64().unwrap();
    assert!((2.0..8.0).contains(&independent), "{v}");
    // Over so few, an exact covariance would show a wide range, and this one lies inside it.
    let range = |key: &str| -> Vec<f64> {
        let r = v[key].as_array().unwrap_or_else(|| panic!("{key}: {v}"));
        r.iter().map(|x| x.as_f64().unwrap()).collect()
    };
    let (coverage_range, nees_range) = (
        range("cov95_coverage_if_exact"),
        range("nees_mean_if_exact"),
    );
    assert!(coverage_range[0] < 0.9 && coverage_range[1] > 0.99, "{v}");
    assert!(nees_range[0] < nees && nees < nees_range[1], "{v}");
    assert_eq!(v["calibration_verdict"], "consistent", "{v}");
    // A status file of another run is refused, not silently paired.
    let short = dir.path().join("short.csv");
    let text = std::fs::read_to_string(&status).unwrap();
    let lines: Vec<&str> = text.lines().take(100).collect();
    std::fs::write(&short, lines.join("\n")).unwrap();
    let out = eval(&short);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("99 rows"));
}

/// Always runs: a status CSV given to `eval --status` that is not one `correct` wrote is refused
/// naming the file and, for a row, its line: empty, a column missing, a row cut short, a number
/// that is not one, a covariance that is none, and an `anchor_yaw` that is no angle (1e300 was
/// taken, as whatever its sine is, where the Python package's `eval` refused it). The rows as
/// written are read.
#[test]
fn a_status_csv_that_is_not_one_is_refused_naming_the_line() {
    let dir = tempfile::tempdir().unwrap();
    let (gt, est) = (dir.path().join("gt.txt"), dir.path().join("est.txt"));
    let pose = |x: f64| format!("1 0 0 {x} 0 1 0 0 0 0 1 0\n");
    std::fs::write(&gt, (0..3).map(|i| pose(i as f64)).collect::<String>()).unwrap();
    std::fs::write(
        &est,
        (0..3).map(|i| pose(i as f64 + 0.5)).collect::<String>(),
    )
    .unwrap();
    // index .. applied_directions, cov_xx, cov_xy, cov_xyaw, cov_yy, cov_yyaw, cov_yawyaw,
    // anchor_yaw, odometry_scale, odometry_scale_sd
    let row = |i: usize, cov_xx: &str, anchor_yaw: &str| {
        format!("{i},accepted,,0.1,1,3,0,0,0,3,{cov_xx},0,0,1,0,0.01,{anchor_yaw},1,0\n")
    };
    let header = lanealign_cli::status_file::HEADER;
    let csv = |rows: [String; 3]| format!("{header}\n{}", rows.concat());
    let good = || [row(0, "1", "0"), row(1, "1", "0"), row(2, "1", "0")];
    let eval = |name: &str, text: &str| {
        let status = dir.path().join(name);
        std::fs::write(&status, text).unwrap();
        let args = [
            "eval",
            "--gt",
            s(&gt),
            "--est",
            s(&est),
            "--status",
            s(&status),
        ];
        lanealign(&[&args[..], &["--frame", "kitti-camera", "--json"]].concat())
    };
    let out = eval("good.csv", &csv(good()));
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    assert!(
        (v["nees_mean"].as_f64().unwrap() - 0.25).abs() < 1e-12,
        "{v}"
    );

    let with_row_1 = |bad: String| {
        let mut rows = good();
        rows[1] = bad;
        csv(rows)
    };
    let cases = [
        (
            "empty.csv",
            String::new(),
            "empty.csv: empty, not a status CSV",
        ),
        (
            "column.csv",
            csv(good()).replacen("cov_xx", "cov_x", 1),
            "column.csv: no column cov_xx",
        ),
        (
            "short.csv",
            with_row_1("1,accepted,,0.1,1,3,0,0,0,3,1,0\n".into()),
            "short.csv:3: too few columns",
        ),
        (
            "word.csv",
            with_row_1(row(1, "one", "0")),
            "word.csv:3: one is not a number",
        ),
        (
            "nan.csv",
            with_row_1(row(1, "NaN", "0")),
            "not finite and positive definite",
        ),
        (
            "yaw.csv",
            with_row_1(row(1, "1", "1e300")),
            "yaw.csv:3: anchor_yaw 1e300 is not an angle",
        ),
    ];
    for (name, text, says) in cases {
        let out = eval(name, &text);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{name}: {err}");
        assert!(err.contains(says), "{name}: {err}");
    }
}

/// `correct --results DIR --gt GT` keeps each run in a folder of its own with `latest` pointing
/// at the newest: the corrected trajectory and status, every effective parameter (what
/// `lanealign params` prints for the same flags), the metrics `eval --status` reports (APE-2D and
/// the covariances' calibration), and the plots; `eval --plot` draws the error plot too.
#[test]
fn correct_keeps_a_results_folder_with_parameters_metrics_and_plots() {
    let dir = tempfile::tempdir().unwrap();
    let lanes = straight_lane(dir.path());
    let line = |y: f64| -> String {
        (0..200)
            .map(|i| format!("{} {} {y} 0 0 0 0 1\n", i as f64 * 0.1, i as f64 * 1.2))
            .collect()
    };
    let (input, gt) = (dir.path().join("in.tum"), dir.path().join("gt.tum"));
    std::fs::write(&input, line(0.8)).unwrap();
    std::fs::write(&gt, line(0.0)).unwrap();
    let results = dir.path().join("results");
    let flags = [
        "--preset",
        "kiss-icp",
        "--method",
        "paper",
        "--set",
        "min_window=20",
    ];
    let run = || {
        let mut args = vec!["correct", "--lanes", s(&lanes), "--format", "tum"];
        args.extend(flags);
        args.extend([s(&input), "--results", s(&results), "--gt", s(&gt)]);
        let out = lanealign(&args);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
    };
    run();
    run();
    // `--status` goes beside `--output`: with a results folder alone it is refused, not ignored.
    let stray = dir.path().join("stray.csv");
    let mut args = vec!["correct", "--lanes", s(&lanes), "--format", "tum"];
    args.extend(flags);
    args.extend([s(&input), "--results", s(&results), "--status", s(&stray)]);
    let refused = lanealign(&args);
    let err = String::from_utf8_lossy(&refused.stderr);
    assert!(
        !refused.status.success() && err.contains("--output"),
        "{err}"
    );
    assert!(!stray.exists());
    // A ground truth that does not pair with the run (TUM stamps none of which match) is refused
    // before anything is written: it left a run folder without metrics, `latest` pointing at it.
    let elsewhere = dir.path().join("elsewhere.tum");
    let later: String = (0..200)
        .map(|i| {
            format!(
                "{} {} 0 0 0 0 0 1\n",
                1000.0 + i as f64 * 0.1,
                i as f64 * 1.2
            )
        })
        .collect();
    std::fs::write(&elsewhere, later).unwrap();
    let mut args = vec!["correct", "--lanes", s(&lanes), "--format", "tum"];
    args.extend(flags);
    args.extend([s(&input), "--results", s(&results), "--gt", s(&elsewhere)]);
    let refused = lanealign(&args);
    let err = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(1), "{err}");
    assert!(
        err.contains("--gt ")
            && err.contains("no estimate stamp lies within 0.01 s of a ground-truth stamp")
            && err.contains("--t-offset shifts the estimate's stamps"),
        "{err}"
    );
    let runs = std::fs::read_dir(&results).unwrap().count();
    assert_eq!(runs, 3, "two run folders and latest");
    let latest = results.join("latest");
    let corrected = std::fs::read_to_string(latest.join("corrected.tum")).unwrap();
    assert_eq!(corrected.lines().count(), 200);
    let status = std::fs::read_to_string(latest.join("status.csv")).unwrap();
    assert_eq!(status.lines().count(), 201);

    let params: toml::Table = std::fs::read_to_string(latest.join("params.toml"))
        .unwrap()
        .parse()
        .unwrap();
    let mut args = vec!["params"];
    args.extend(flags);
    let printed: toml::Table = String::from_utf8(lanealign(&args).stdout)
        .unwrap()
        .parse()
        .unwrap();
    assert_eq!(params["params"], printed["params"]);
    assert_eq!(params["corrector"], printed["corrector"]);
    assert_eq!(params["at_rate"], printed["at_rate"]);
    assert_eq!(params["run"]["map"].as_str(), Some("lanes-csv"));

    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(latest.join("metrics.json")).unwrap())
            .unwrap();
    let out = lanealign(&[
        "eval",
        "--gt",
        s(&gt),
        "--est",
        s(&latest.join("corrected.tum")),
        "--status",
        s(&latest.join("status.csv")),
        "--format",
        "tum",
        "--json",
        "--plot",
        s(&dir.path().join("eval.svg")),
    ]);
    let eval: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(metrics["corrected"]["ape2d_mean_m"], eval["ape2d_mean_m"]);
    for key in [
        "cov95_coverage",
        "nees_mean",
        "independent_samples",
        "cov95_coverage_if_exact",
        "nees_mean_if_exact",
        "calibration_verdict",
    ] {
        assert!(!eval[key].is_null(), "{key}: {eval}");
        assert_eq!(metrics["calibration"][key], eval[key], "{key}");
    }
    let raw_mean = metrics["raw"]["ape2d_mean_m"].as_f64().unwrap();
    assert!((raw_mean - 0.8).abs() < 1e-9, "{metrics}");
    assert!(eval["ape2d_mean_m"].as_f64().unwrap() < raw_mean);

    let svg = |name: &Path| std::fs::read_to_string(name).unwrap();
    let trajectory = svg(&latest.join("trajectory.svg"));
    for legend in [
        "lanes (OpenStreetMap)",
        "ground truth",
        "raw odometry",
        "corrected",
        "(m)",
    ] {
        assert!(
            trajectory.contains(legend),
            "trajectory plot lacks {legend}"
        );
    }
    for plot in [
        svg(&latest.join("error.svg")),
        svg(&dir.path().join("eval.svg")),
    ] {
        assert!(plot.starts_with("<svg") && plot.contains("distance driven (m)"));
    }

    // The ground truth whose clock is 1000 s ahead pairs as `eval --t-offset 1000` pairs it.
    let mut args = vec!["correct", "--lanes", s(&lanes), "--format", "tum"];
    args.extend(flags);
    args.extend([s(&input), "--results", s(&results), "--gt", s(&elsewhere)]);
    args.extend(["--t-offset", "1000"]);
    let out = lanealign(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(latest.join("metrics.json")).unwrap())
            .unwrap();
    assert_eq!(metrics["raw"]["poses"], 200, "{metrics}");
    assert!((metrics["raw"]["ape2d_mean_m"].as_f64().unwrap_or(f64::NAN) - 0.8).abs() < 1e-9);
    let out = lanealign(&[
        "eval",
        "--gt",
        s(&elsewhere),
        "--est",
        s(&latest.join("corrected.tum")),
        "--format",
        "tum",
        "--t-offset",
        "1000",
        "--json",
    ]);
    let eval: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_default();
    assert_eq!(
        metrics["corrected"]["ape2d_mean_m"], eval["ape2d_mean_m"],
        "{eval}"
    );
    // Without --gt there is nothing to pair.
    let mut args = vec!["correct", "--lanes", s(&lanes), "--format", "tum"];
    args.extend(flags);
    args.extend([s(&input), "--results", s(&results), "--t-offset", "1000"]);
    assert_eq!(lanealign(&args).status.code(), Some(2));
}

/// `lanealign --version` and `lanealignd --version` say their wire version, so that an operator
/// can tell whether a client and a daemon can talk (docs/wire.md, "Wire version").
#[test]
fn the_version_lines_name_the_wire() {
    let daemon = lanealign_cli::daemon_process::daemon_binary().expect("lanealignd is built");
    for program in [Path::new(env!("CARGO_BIN_EXE_lanealign")), daemon.as_path()] {
        let out = Command::new(program).arg("--version").output().unwrap();
        let line = String::from_utf8_lossy(&out.stdout);
        assert!(out.status.success(), "{program:?}: {line}");
        assert!(
            line.trim_end().ends_with(&format!(
                " {} (wire {})",
                env!("CARGO_PKG_VERSION"),
                lanealign_wire::service::WIRE_VERSION
            )),
            "{program:?}: {line}"
        );
    }
}

/// `soak` checks its arguments before it starts a daemon: a rate of 1e300 asked for an
/// allocation of 8e17 bytes (SIGABRT), 2^64 - 1 sources panicked on a capacity overflow, 10^5
/// sources started a daemon that never got ready, a rate that made no pose printed NaN, and a
/// rate of 1e-300 Hz for 1e300 s overflowed the times of the phase's quarters.
#[test]
fn soak_refuses_what_it_cannot_run_before_starting_anything() {
    for (args, says) in [
        (
            &["--sources", "0"][..],
            "--sources 0: must be between 1 and 256",
        ),
        (
            &["--sources", "100000"],
            "--sources 100000: must be between 1",
        ),
        (
            &["--sources", "18446744073709551615"],
            "--sources 18446744073709551615",
        ),
        (
            &["--rate", "1e300"],
            "--rate 1e300: must be 0.001 to 100000 Hz",
        ),
        (&["--rate", "NaN"], "--rate NaN: must be 0.001 to 100000 Hz"),
        (
            &["--rate", "1e-300"],
            "--rate 1e-300: must be 0.001 to 100000 Hz",
        ),
        // A duration that still gives a pose overflowed the times of the phase's quarters.
        (
            &["--rate", "1e-300", "--duration", "1e300"],
            "--rate 1e-300",
        ),
        (
            &["--rate", "0.001", "--duration", "1"],
            "makes 0.0 poses per source: must be between 1 and 1e7",
        ),
        (&["--duration", "1e300"], "makes 1e302 poses per source"),
        (
            &["--duration", "inf"],
            "--duration inf: must be a positive number of seconds",
        ),
        // A strategy named twice ran the same two phases twice.
        (
            &["--waits", "event,busy-spin,event"],
            "--waits: event is named twice",
        ),
    ] {
        let started = std::time::Instant::now();
        assert_refused(&[&["soak"][..], args].concat(), says);
        assert!(
            started.elapsed().as_secs() < 5,
            "{args:?} took {:?}",
            started.elapsed()
        );
    }
}

/// `replay --rate` takes 0.001 to 100000 Hz or `max`: at 1e-300 Hz the time the second pose was
/// due overflowed and the replay panicked once a daemon answered the first.
#[test]
fn replay_refuses_a_rate_it_cannot_keep() {
    let dir = tempfile::tempdir().unwrap();
    let output = dir.path().join("out.txt");
    for rate in ["1e-300", "0.0009", "1e300", "NaN", "inf"] {
        let out = lanealign(&[
            "replay",
            "--source",
            "lidar",
            "--rate",
            rate,
            "poses.txt",
            "-o",
            s(&output),
        ]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{rate}: {err}");
        assert!(
            err.contains(&format!(
                "rate '{rate}': expected 0.001 to 100000 Hz, or 'max'"
            )),
            "{rate}: {err}"
        );
    }
}
