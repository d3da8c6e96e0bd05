//! The robust method against the paper's on the real KITTI runs, on lanes derived from OSM
//! (docs/method.md): what it must achieve, and that smoothing only bounds the output's jumps.

use std::sync::Arc;

use lanealign_cli::synthetic::heading_drifted;
use lanealign_core::confidence::position_covariance_in;
use lanealign_core::corrector::{MatchMode, Status};
use lanealign_core::geo::{Anchor, MapPlane, Projection};
use lanealign_core::lane_map::LaneMap;
use lanealign_core::metrics::{
    ape_2d, calibration, output_jumps, scaled_steps, Ape2d, Calibration, OutputJumps, Verdict,
};
use lanealign_core::params::{Method, Params, Preset};
use lanealign_core::plausibility;
use lanealign_core::pose::{apply_planar_correction, AxisConvention, Pose3};
use lanealign_core::se2::{distance, wrap_angle, Se2};
use lanealign_core::smoothing::Smoothing;
use lanealign_core::source_corrector::{
    correct_stamped_trajectory, correct_trajectory, counts, CorrectedPose, Placement,
};
use lanealign_core::trajectory::{read, Format};
use lanealign_map::compile::{compile, CompileOptions};
use lanealign_map::osm_lanes::LaneOptions;
use lanealign_tests::{kitti_anchor, shared_data, SEQUENCES};

struct Sequence {
    name: &'static str,
    /// Lanes in the paper's geometry.
    paper_map: Arc<LaneMap>,
    /// Lanes in lanealign's default geometry.
    map: Arc<LaneMap>,
    anchor: Anchor,
    /// The plane both maps are in (the anchor's origin, KITTI's projection).
    plane: MapPlane,
    gt: Vec<Pose3>,
}

struct Run {
    /// Poses taken for jumps of the odometry.
    odometry_jumps: usize,
    raw: Ape2d,
    corrected: Ape2d,
    jumps: OutputJumps,
    calibration: Calibration,
}

fn sequences(data: &std::path::Path) -> Vec<Sequence> {
    SEQUENCES.iter().map(|&name| sequence(data, name)).collect()
}

fn sequence(data: &std::path::Path, name: &'static str) -> Sequence {
    let anchor = kitti_anchor(data, name);
    let osm = data.join(format!("osm/kitti_{name}.osm"));
    let lanes = |lanes: LaneOptions| {
        let options = CompileOptions {
            origin: Some((anchor.lat(), anchor.lon())),
            projection: Projection::Kitti,
            lanes,
        };
        Arc::new(compile(std::slice::from_ref(&osm), &options).unwrap().map)
    };
    let gt = read(&data.join(format!("kitti/poses/{name}.txt")), Format::Kitti).unwrap();
    Sequence {
        name,
        paper_map: lanes(LaneOptions::for_method(Method::Paper)),
        map: lanes(LaneOptions::for_method(Method::Robust)),
        anchor,
        plane: MapPlane::new(Projection::Kitti, anchor.lat(), anchor.lon()),
        gt: gt.poses,
    }
}

fn run(
    data: &std::path::Path,
    s: &Sequence,
    odometry: &str,
    method: Method,
    preset: Preset,
    smoothing: Option<Smoothing>,
) -> Run {
    run_with(data, s, odometry, method, method.params(preset), smoothing).0
}

/// [`run`] with `params` for `method`; also the corrected poses and their covariances (planar,
/// the odometry's frame), pose by pose.
fn run_with(
    data: &std::path::Path,
    s: &Sequence,
    odometry: &str,
    method: Method,
    params: Params,
    smoothing: Option<Smoothing>,
) -> (Run, Vec<Pose3>, Vec<[[f64; 2]; 2]>) {
    let c = run_poses(
        s,
        &odometry_of(data, odometry, s),
        method,
        params,
        smoothing,
    );
    (c.run, c.est, c.cov)
}

/// The shared `odometry` run's poses of sequence `s` (KITTI's camera convention).
fn odometry_of(data: &std::path::Path, odometry: &str, s: &Sequence) -> Vec<Pose3> {
    read(
        &data.join(format!("odometry/{odometry}/{}.txt", s.name)),
        Format::Kitti,
    )
    .unwrap()
    .poses
}

/// What [`run_poses`] gives.
struct Corrected {
    run: Run,
    /// The corrected poses (planar, the odometry's frame).
    est: Vec<Pose3>,
    /// Their position covariances (the odometry's frame).
    cov: Vec<[[f64; 2]; 2]>,
    /// What the corrector answered for each pose.
    answers: Vec<CorrectedPose>,
}

/// [`run_with`] on the odometry `odom` (KITTI's camera convention).
fn run_poses(
    s: &Sequence,
    odom: &[Pose3],
    method: Method,
    params: Params,
    smoothing: Option<Smoothing>,
) -> Corrected {
    let cam = AxisConvention::KittiCamera;
    let anchored_from_odom = s.anchor.anchored_from_odom(&s.plane);
    let placement = Placement {
        convention: cam,
        anchored_from_odom,
        smoothing,
    };
    let map = match method {
        Method::Paper => &s.paper_map,
        Method::Robust => &s.map,
    };
    let out = correct_trajectory(map.clone(), params, MatchMode::Fast, placement, odom);
    let planar = |v: &[Pose3]| v.iter().map(|p| cam.to_planar(p)).collect::<Vec<_>>();
    let gt = planar(&s.gt);
    let raw = planar(odom);
    let est = planar(&out.iter().map(|c| c.pose).collect::<Vec<_>>());
    let scale_after: Vec<f64> = out.iter().map(|c| c.odometry_scale).collect();
    let odom_from_map = anchored_from_odom.inverse();
    let cov: Vec<[[f64; 2]; 2]> = out
        .iter()
        .map(|c| position_covariance_in(&odom_from_map, &c.covariance))
        .collect();
    let run = Run {
        odometry_jumps: out
            .iter()
            .filter(|c| matches!(c.status, Status::OdometryJump { .. }))
            .count(),
        raw: ape_2d(&gt, &raw).unwrap(),
        corrected: ape_2d(&gt, &est).unwrap(),
        jumps: output_jumps(&scaled_steps(&raw, &scale_after), &est).unwrap(),
        calibration: calibration(&gt, &est, &cov).unwrap(),
    };
    Corrected {
        run,
        est,
        cov,
        answers: out,
    }
}

fn mean(runs: &[Run], f: impl Fn(&Run) -> f64) -> f64 {
    runs.iter().map(f).sum::<f64>() / runs.len() as f64
}

#[test]
fn robust_beats_the_paper_and_smooth_output_glides() {
    let Some(data) = shared_data() else { return };
    let seqs = sequences(&data);
    // The robust method's means: issue 14's bars (1.06 and 7.45 m; today 1.001 and 7.131 m, and
    // 1.004-1.006 / 7.127-7.130 m over copies of the runs moved by a micrometre).
    for (odometry, preset, paper_mean, bar) in [
        ("lidar", Preset::KissIcp, 1.422, 1.06),
        ("stereo_vo", Preset::OrbSlam3, 9.849, 7.45),
    ] {
        let paper: Vec<Run> = seqs
            .iter()
            .map(|s| run(&data, s, odometry, Method::Paper, preset, None))
            .collect();
        let robust: Vec<Run> = seqs
            .iter()
            .map(|s| run(&data, s, odometry, Method::Robust, preset, None))
            .collect();
        let smooth: Vec<Run> = seqs
            .iter()
            .map(|s| {
                let limits = Some(Smoothing::default());
                run(&data, s, odometry, Method::Robust, preset, limits)
            })
            .collect();
        let paper_mean_now = mean(&paper, |r| r.corrected.mean_m);
        let robust_mean = mean(&robust, |r| r.corrected.mean_m);
        let smooth_mean = mean(&smooth, |r| r.corrected.mean_m);
        println!(
            "{odometry} {}: raw {:.3} paper {paper_mean_now:.3} robust {robust_mean:.3} smooth {smooth_mean:.3}",
            preset.name(),
            mean(&robust, |r| r.raw.mean_m)
        );
        assert!(
            (paper_mean_now - paper_mean).abs() < 5e-4,
            "{odometry}: the paper's method moved: {paper_mean_now}"
        );
        assert!(
            robust_mean <= bar,
            "{odometry}: robust {robust_mean} > {bar}"
        );
        assert!(
            (smooth_mean - robust_mean).abs() <= 0.1 * robust_mean,
            "{odometry}: smooth {smooth_mean} vs {robust_mean}"
        );
        for (s, sm) in seqs.iter().zip(&smooth) {
            assert!(
                sm.jumps.max_position_m <= 0.05 + 1e-9 && sm.jumps.max_yaw_deg <= 0.1 + 1e-9,
                "{odometry} {}: smooth output jumps {:?}",
                s.name,
                sm.jumps
            );
        }
        // The unsmoothed output does jump: the bound above is smoothing's doing.
        let largest = robust
            .iter()
            .map(|r| r.jumps.max_position_m)
            .fold(0.0, f64::max);
        assert!(largest > 1.0, "{odometry}: unsmoothed jumps {largest}");
        // Never worse than the odometry it corrects: visual odometry within 5 cm of raw on
        // every sequence; LiDAR within 0.2 m (09: +0.122 m, docs/method.md, "Ablation").
        let allowed = if odometry == "lidar" { 0.2 } else { 0.05 };
        for (s, r) in seqs.iter().zip(&robust) {
            let excess = r.corrected.mean_m - r.raw.mean_m;
            println!(
                "{odometry} {} {}: raw {:.3} robust {:.3} ({excess:+.3}); cov95 coverage {:.3}, NEES {:.2}",
                preset.name(),
                s.name,
                r.raw.mean_m,
                r.corrected.mean_m,
                r.calibration.cov95_coverage,
                r.calibration.nees_mean
            );
            assert!(excess <= allowed, "{odometry} {}: {excess:+.3} m", s.name);
            // The covariance is not yet calibrated on every sequence (docs/method.md,
            // "Confidence"); this guards what it achieves today against regressions.
            assert!(
                r.calibration.cov95_coverage >= 0.4,
                "{odometry} {}: {:?}",
                s.name,
                r.calibration
            );
            // Where it misses, it errs on the safe side: no sequence's errors are beyond what an
            // exact covariance shows over as many independent errors, but on `stereo_vo` 01, the
            // highway's scale drift (docs/method.md, "The verdict").
            let check = r.calibration.check();
            if (odometry, s.name) != ("stereo_vo", "01") {
                assert_ne!(
                    check.verdict,
                    Verdict::TooConfident,
                    "{odometry} {}: {check:?}",
                    s.name
                );
            }
        }
    }
}

/// No catastrophic steps: with every preset on both runs, every sequence's largest error stays
/// within its raw largest error + 1 m (the paper's method reached +82.7 m: liodom on `lidar` 06).
#[test]
fn no_catastrophic_steps_with_any_preset_on_either_run() {
    let Some(data) = shared_data() else { return };
    let seqs = sequences(&data);
    for odometry in ["lidar", "stereo_vo"] {
        for preset in Preset::ALL {
            for s in &seqs {
                let r = run(&data, s, odometry, Method::Robust, preset, None);
                assert_eq!(
                    r.odometry_jumps,
                    0,
                    "{odometry} {} {}: no step of a real drive is a jump",
                    preset.name(),
                    s.name
                );
                let excess = r.corrected.max_m - r.raw.max_m;
                assert!(
                    excess <= 1.0,
                    "{odometry} {} {}: max error {:.2} m vs raw {:.2} m",
                    preset.name(),
                    s.name,
                    r.corrected.max_m,
                    r.raw.max_m
                );
            }
        }
    }
}

/// docs/method.md, "Measured 2026-12-07": a heading that drifts 0.06 degree per 100 m (the
/// LiDAR presets say 0.2) and a ratio of 3 keep every sequence of the shared LiDAR run within
/// raw + 0.05 m with both LiDAR presets (the defaults leave 09 0.12 and 0.18 m above), and pay on
/// 00, whose odometry turns faster than that: the mean rises and 00's covariance is too
/// confident. Why it is no preset's default.
#[test]
fn a_slower_heading_drift_keeps_lidar_odometry_and_pays_on_00() {
    let Some(data) = shared_data() else { return };
    let seqs = sequences(&data);
    for preset in [Preset::KissIcp, Preset::Liodom] {
        let default = Method::Robust.params(preset);
        let slower = Params {
            yaw_drift_var_per_m: 1e-8,
            min_evidence_ratio: 3.0,
            ..default
        };
        let lidar = |params: Params| -> Vec<Run> {
            let robust = Method::Robust;
            seqs.iter()
                .map(|s| run_with(&data, s, "lidar", robust, params, None).0)
                .collect()
        };
        let (kept, now) = (lidar(slower), lidar(default));
        let worst = |runs: &[Run]| {
            runs.iter()
                .map(|r| r.corrected.mean_m - r.raw.mean_m)
                .fold(f64::NEG_INFINITY, f64::max)
        };
        let name = preset.name();
        assert!(worst(&kept) <= 0.05, "{name}: {:+.3} m", worst(&kept));
        assert!(
            worst(&now) > 0.1,
            "{name}: the default {:+.3} m",
            worst(&now)
        );
        let (m_kept, m_now) = (
            mean(&kept, |r| r.corrected.mean_m),
            mean(&now, |r| r.corrected.mean_m),
        );
        assert!(
            m_kept > m_now + 0.1,
            "{name}: {m_kept:.3} against {m_now:.3} m"
        );
        let (zero_kept, zero_now) = (&kept[0].calibration, &now[0].calibration);
        assert_eq!(seqs[0].name, "00");
        assert!(
            zero_kept.cov95_coverage < 0.7 && zero_now.cov95_coverage > 0.95,
            "{name} 00: coverage {:.3} against {:.3}",
            zero_kept.cov95_coverage,
            zero_now.cov95_coverage
        );
    }
}

/// Odometry of any accuracy, made from the ground truth with a heading that drifts as a random
/// walk (docs/method.md, "Odometry of any accuracy"). An odometry better than the map comes out
/// worse on nearly every sequence: the corrector moves it onto lanes that are off by up to 1.4 m
/// on average. One that drifts as the kiss-icp preset assumes (0.2 degree per square root of
/// 100 m) comes out no worse than raw + 0.05 m on any sequence, and a third better on average.
/// And the orb-slam3 preset's scale estimate, given the ground truth (whose scale is right),
/// misreads the highway of 01.
#[test]
fn an_odometry_better_than_the_map_is_not_improved_and_one_that_drifts_is() {
    let Some(data) = shared_data() else { return };
    let seqs = sequences(&data);
    let cam = AxisConvention::KittiCamera;
    let robust = Method::Robust;
    let drifted = |level: f64| -> Vec<Run> {
        seqs.iter()
            .enumerate()
            .map(|(i, s)| {
                let odom = heading_drifted(&s.gt, cam, level, 1000 + i as u64);
                run_poses(s, &odom, robust, robust.params(Preset::KissIcp), None).run
            })
            .collect()
    };
    let worse = |runs: &[Run]| {
        runs.iter()
            .filter(|r| r.corrected.mean_m > r.raw.mean_m + 0.05)
            .count()
    };
    let exact = drifted(0.0);
    let floor = mean(&exact, |r| r.corrected.mean_m);
    assert!(worse(&exact) >= 9, "{} of 10 worse", worse(&exact));
    assert!(floor > 0.6, "ground truth corrected to {floor:.3} m");
    let at_the_presets_drift = drifted(0.2);
    assert_eq!(worse(&at_the_presets_drift), 0);
    assert!(
        mean(&at_the_presets_drift, |r| r.corrected.mean_m)
            < mean(&at_the_presets_drift, |r| r.raw.mean_m) / 1.5
    );
    let highway = seqs.iter().find(|s| s.name == "01").unwrap();
    let visual = robust.params(Preset::OrbSlam3);
    let (with_scale, without) = (
        run_poses(highway, &highway.gt, robust, visual, None).run,
        run_poses(
            highway,
            &highway.gt,
            robust,
            Params {
                scale_sigma: 0.0,
                ..visual
            },
            None,
        )
        .run,
    );
    assert!(
        with_scale.corrected.mean_m > 2.5 && without.corrected.mean_m < 2.0,
        "01, ground truth: {:.3} m with the scale estimated, {:.3} m without",
        with_scale.corrected.mean_m,
        without.corrected.mean_m
    );
}

/// `poses` at ten times their rate: nine poses between each two, the translation interpolated,
/// the rotation the earlier pose's (the corrector uses the planar position only).
fn ten_times_the_rate(poses: &[Pose3]) -> Vec<Pose3> {
    let mut out: Vec<Pose3> = poses
        .windows(2)
        .flat_map(|w| {
            (0..10).map(move |j| Pose3 {
                rotation: w[0].rotation,
                translation: w[0].translation
                    + (w[1].translation - w[0].translation) * (j as f64 / 10.0),
            })
        })
        .collect();
    out.extend(poses.last());
    out
}

/// The presets' pose counts were chosen for 10 Hz odometry: fed the same drive at 100 Hz, the
/// window held a tenth of the road and KITTI 00 came out at 1.38 m instead of 1.10 m (the paper's
/// method at 23.2 m instead of 1.66 m). With the source's rate set, every tenth pose enters the
/// window and the drive is corrected as at 10 Hz.
#[test]
fn a_faster_source_is_corrected_as_at_the_presets_rate() {
    let Some(data) = shared_data() else { return };
    let s = sequence(&data, "00");
    let cam = AxisConvention::KittiCamera;
    let odom = read(&data.join("odometry/lidar/00.txt"), Format::Kitti).unwrap();
    let fast_odom = ten_times_the_rate(&odom.poses);
    let planar = |v: &[Pose3]| v.iter().map(|p| cam.to_planar(p)).collect::<Vec<_>>();
    let gt = planar(&s.gt);
    let fast_gt = planar(&ten_times_the_rate(&s.gt));
    let placement = Placement {
        convention: cam,
        anchored_from_odom: s.anchor.anchored_from_odom(&s.plane),
        smoothing: None,
    };
    for (method, map) in [(Method::Paper, &s.paper_map), (Method::Robust, &s.map)] {
        let params = method.params(Preset::KissIcp);
        let mut at_rate = params;
        at_rate.odometry_rate_hz = 100.0;
        let correct = |params, poses: &[Pose3]| {
            correct_trajectory(map.clone(), params, MatchMode::Fast, placement, poses)
        };
        let ape = |gt: &[Pose3], out: &[CorrectedPose]| {
            let est: Vec<Pose3> = out.iter().map(|c| c.pose).collect();
            ape_2d(gt, &planar(&est)).unwrap().mean_m
        };
        let slow = correct(params, &odom.poses);
        let fast = correct(at_rate, &fast_odom);
        let unset = correct(params, &fast_odom);
        let (slow_m, fast_m, unset_m) =
            (ape(&gt, &slow), ape(&fast_gt, &fast), ape(&fast_gt, &unset));
        println!(
            "{}: 10 Hz {slow_m:.3} m; 100 Hz with odometry_rate_hz = 100 {fast_m:.3} m, without {unset_m:.3} m",
            method.name()
        );
        assert_eq!(counts(&fast), counts(&slow), "{}", method.name());
        assert!(
            (fast_m - slow_m).abs() < 0.01,
            "{}: {fast_m} m at 100 Hz against {slow_m} m at 10 Hz",
            method.name()
        );
        if method == Method::Paper {
            // Nothing but the window's poses decides the paper's corrections: equal bit for bit.
            for (k, c) in slow.iter().enumerate() {
                assert_eq!(fast[10 * k].pose, c.pose, "pose {k}");
                assert_eq!(fast[10 * k].status, c.status, "pose {k}");
            }
        }
    }
}

/// A slower source has its window counts scaled down by its rate: fed every fifth pose (2 Hz),
/// the presets' 150-pose `min_window` waited 75 s for the first correction and spanned 750 m of
/// road, and the visual odometry of 02 was never corrected (92.4 m, raw 92.4 m). With the
/// source's rate set, the window spans the same time as at 10 Hz.
#[test]
fn a_slower_source_is_corrected_as_at_the_presets_rate() {
    let Some(data) = shared_data() else { return };
    let cam = AxisConvention::KittiCamera;
    let planar = |v: &[Pose3]| v.iter().map(|p| cam.to_planar(p)).collect::<Vec<_>>();
    let every_fifth = |v: &[Pose3]| v.iter().step_by(5).copied().collect::<Vec<_>>();
    for (name, odometry, preset) in [
        ("00", "lidar", Preset::KissIcp),
        ("02", "stereo_vo", Preset::OrbSlam3),
    ] {
        let s = sequence(&data, name);
        let odom = read(
            &data.join(format!("odometry/{odometry}/{name}.txt")),
            Format::Kitti,
        )
        .unwrap();
        let placement = Placement {
            convention: cam,
            anchored_from_odom: s.anchor.anchored_from_odom(&s.plane),
            smoothing: None,
        };
        let params = Method::Robust.params(preset);
        let mut at_rate = params;
        at_rate.odometry_rate_hz = 2.0;
        let ape = |gt: &[Pose3], params, poses: &[Pose3]| {
            let out = correct_trajectory(s.map.clone(), params, MatchMode::Fast, placement, poses);
            let est: Vec<Pose3> = out.iter().map(|c| c.pose).collect();
            ape_2d(&planar(gt), &planar(&est)).unwrap().mean_m
        };
        let (slow_odom, slow_gt) = (every_fifth(&odom.poses), every_fifth(&s.gt));
        let full = ape(&s.gt, params, &odom.poses);
        let set = ape(&slow_gt, at_rate, &slow_odom);
        let unset = ape(&slow_gt, params, &slow_odom);
        println!(
            "{odometry} {name}: 10 Hz {full:.3} m; 2 Hz with odometry_rate_hz = 2 {set:.3} m, \
             without {unset:.3} m"
        );
        assert!(
            set < full + 0.1,
            "{odometry} {name}: {set} m at 2 Hz, {full} m at 10 Hz"
        );
        assert!(unset > set + 0.25, "{odometry} {name}: the setting matters");
    }
}

/// An odometry whose scale is off has it estimated and taken out (docs/method.md, "Scale"): the
/// stereo visual odometry of 01, 8 % short on the highway, by the orb-slam3 preset's default;
/// the LiDAR odometry of 08 made 3 % long and of 00 1 % short, with `scale_sigma` set. Without
/// the estimate the rigid window cannot fit such a drive's shape to the lanes.
#[test]
fn an_odometry_whose_scale_is_off_has_it_estimated() {
    let Some(data) = shared_data() else { return };
    let cam = AxisConvention::KittiCamera;
    let planar = |v: &[Pose3]| v.iter().map(|p| cam.to_planar(p)).collect::<Vec<_>>();
    let scaled = |v: &[Pose3], factor: f64| -> Vec<Pose3> {
        v.iter()
            .map(|p| Pose3 {
                rotation: p.rotation,
                translation: p.translation * factor,
            })
            .collect()
    };
    for (name, odometry, preset, factor, set_sigma, at_most) in [
        ("01", "stereo_vo", Preset::OrbSlam3, 1.0, None, 0.7),
        ("08", "lidar", Preset::KissIcp, 1.03, Some(0.05), 0.5),
        ("00", "lidar", Preset::KissIcp, 0.99, Some(0.05), 0.6),
    ] {
        let s = sequence(&data, name);
        let odom = read(
            &data.join(format!("odometry/{odometry}/{name}.txt")),
            Format::Kitti,
        )
        .unwrap();
        let poses = scaled(&odom.poses, factor);
        let placement = Placement {
            convention: cam,
            anchored_from_odom: s.anchor.anchored_from_odom(&s.plane),
            smoothing: None,
        };
        let mut params = Method::Robust.params(preset);
        if let Some(sigma) = set_sigma {
            assert_eq!(params.scale_sigma, 0.0, "{}: off by default", preset.name());
            params.scale_sigma = sigma;
        }
        let mut without = params;
        without.scale_sigma = 0.0;
        let correct =
            |params| correct_trajectory(s.map.clone(), params, MatchMode::Fast, placement, &poses);
        let ape = |out: &[CorrectedPose]| {
            let est: Vec<Pose3> = out.iter().map(|c| c.pose).collect();
            ape_2d(&planar(&s.gt), &planar(&est)).unwrap().mean_m
        };
        let (with_scale, without_scale) = (correct(params), correct(without));
        let (with_m, without_m) = (ape(&with_scale), ape(&without_scale));
        let estimated = with_scale[with_scale.len() - 1].odometry_scale;
        println!(
            "{odometry} {name} x{factor}: {with_m:.3} m with the scale estimated (steps x{estimated:.4} \
             at the end), {without_m:.3} m without"
        );
        assert!(
            with_m < at_most * without_m,
            "{odometry} {name}: {with_m} vs {without_m}"
        );
        // The estimate goes the right way: the odometry made too long has its steps shortened;
        // the others (01's visual odometry measures 0.917 of the road) lengthened.
        if factor > 1.0 {
            assert!(estimated < 0.99, "{odometry} {name}: {estimated}");
        } else {
            assert!(estimated > 1.005, "{odometry} {name}: {estimated}");
        }
    }
}

/// KITTI 00's LiDAR odometry placed by its anchor, corrected with the robust method's kiss-icp
/// preset: the drive the tests that alter it start from.
struct Drive00 {
    sequence: Sequence,
    placement: Placement,
    /// The odometry (KITTI camera axes).
    odom: Vec<Pose3>,
    /// Ground truth, planar.
    gt: Vec<Pose3>,
}

impl Drive00 {
    const CAM: AxisConvention = AxisConvention::KittiCamera;

    fn load(data: &std::path::Path) -> Drive00 {
        let sequence = sequence(data, "00");
        let odom = read(&data.join("odometry/lidar/00.txt"), Format::Kitti).unwrap();
        Drive00 {
            placement: Placement {
                convention: Self::CAM,
                anchored_from_odom: sequence.anchor.anchored_from_odom(&sequence.plane),
                smoothing: None,
            },
            gt: Self::planar(&sequence.gt),
            odom: odom.poses,
            sequence,
        }
    }

    fn params() -> Params {
        Method::Robust.params(Preset::KissIcp)
    }

    fn correct(&self, params: Params, poses: &[Pose3]) -> Vec<CorrectedPose> {
        let map = self.sequence.map.clone();
        correct_trajectory(map, params, MatchMode::Fast, self.placement, poses)
    }

    /// [`Drive00::correct`] with a stamp (seconds) for each pose.
    fn correct_stamped(
        &self,
        params: Params,
        poses: &[Pose3],
        stamps_s: &[f64],
    ) -> Vec<CorrectedPose> {
        let map = self.sequence.map.clone();
        let stamps = Some(stamps_s);
        correct_stamped_trajectory(map, params, MatchMode::Fast, self.placement, poses, stamps)
    }

    fn planar(poses: &[Pose3]) -> Vec<Pose3> {
        poses.iter().map(|p| Self::CAM.to_planar(p)).collect()
    }

    /// The mean APE-2D of `est` (one pose per ground-truth pose, camera axes).
    fn ape(&self, est: &[Pose3]) -> f64 {
        ape_2d(&self.gt, &Self::planar(est)).unwrap().mean_m
    }
}

/// Cars stand at red lights; KITTI's drives hardly do. KITTI 00's LiDAR odometry with a minute's
/// stop (600 poses, the odometry jittering by up to 2 cm about the stopping point) every 500
/// poses: with the robust method the moving poses are corrected bit for bit as without the stops,
/// and every standing pose gets the correction in force. Without the standstill setting the
/// stops filled the window with one spot and counted the jitter as road. The same for an
/// odometry that publishes every estimate twice. These stops come within one pose, faster than
/// a car brakes: that is an odometry that froze, which the stall watch takes as one (checked
/// below), so the stops are corrected with it off.
#[test]
fn stops_at_red_lights_change_no_correction_of_the_drive() {
    let Some(data) = shared_data() else { return };
    let drive = Drive00::load(&data);
    let mut stopped: Vec<(Pose3, Option<usize>)> = Vec::new();
    for (i, &p) in drive.odom.iter().enumerate() {
        stopped.push((p, Some(i)));
        if i % 500 == 250 {
            stopped.extend((0..600).map(|k| {
                let k = k as f64;
                let mut jittered = p;
                jittered.translation.x += 0.02 * (1.7 * k).sin();
                jittered.translation.z += 0.02 * (2.3 * k).cos();
                (jittered, None)
            }));
        }
    }
    let poses: Vec<Pose3> = stopped.iter().map(|&(p, _)| p).collect();
    let watched = Drive00::params();
    let params = Params {
        watch_stalls: false,
        ..watched
    };
    let correct = |params, poses: &[Pose3]| drive.correct(params, poses);
    // The stall watch takes the first stop, which falls from 9 m/s to standing within a pose,
    // for an odometry that froze while the vehicle drove on: the covariance widens along the
    // road by the distance at the speed before it, 600 poses of it.
    let first_stop = 251;
    let frozen = correct(watched, &poses[..first_stop + 600]);
    let sd_m = |c: &CorrectedPose| (c.covariance[0][0] + c.covariance[1][1]).sqrt();
    assert!(sd_m(&frozen[first_stop - 1]) < 3.0);
    assert!(sd_m(&frozen[first_stop + 599]) > 300.0);
    // The mean APE-2D of the moving poses.
    let moving_ape = |out: &[CorrectedPose]| {
        let est: Vec<Pose3> = stopped
            .iter()
            .zip(out)
            .filter(|((_, index), _)| index.is_some())
            .map(|(_, c)| c.pose)
            .collect();
        drive.ape(&est)
    };
    let without_stops = correct(params, &drive.odom);
    let with_stops = correct(params, &poses);
    for (j, (c, &(_, index))) in with_stops.iter().zip(&stopped).enumerate() {
        match index {
            Some(i) => {
                assert_eq!(c.pose, without_stops[i].pose, "pose {i}");
                assert_eq!(c.status, without_stops[i].status, "pose {i}");
            }
            None => {
                let before = &with_stops[j - 1];
                assert_eq!(
                    c.status,
                    Status::Carried {
                        window_len: before.status.window_len()
                    },
                    "pose {j}"
                );
                assert_eq!(c.map_from_odom, before.map_from_odom, "pose {j}");
            }
        }
    }
    let mut off = params;
    off.standstill_speed_mps = 0.0;
    let (stops_on, stops_off, none) = (
        moving_ape(&with_stops),
        moving_ape(&correct(off, &poses)),
        drive.ape(&without_stops.iter().map(|c| c.pose).collect::<Vec<_>>()),
    );
    println!(
        "KITTI 00 lidar, {} stops: {stops_on:.3} m on the moving poses ({none:.3} m without stops); \
         with standstill_speed_mps = 0 {stops_off:.3} m",
        (stopped.len() - drive.odom.len()) / 600
    );
    assert!(
        stops_off > none + 0.05,
        "the stops matter without the setting"
    );

    // Smoothed, a standing vehicle's output moves only as its odometry does: a correction
    // still gliding in waits until the vehicle moves again.
    let smoothed = correct_trajectory(
        drive.sequence.map.clone(),
        params,
        MatchMode::Fast,
        Placement {
            smoothing: Some(Smoothing::default()),
            ..drive.placement
        },
        &poses,
    );
    let position = |p: &Pose3| Drive00::CAM.to_planar(p).translation;
    for j in 1..poses.len() {
        if stopped[j].1.is_none() {
            let out = (position(&smoothed[j].pose) - position(&smoothed[j - 1].pose)).norm();
            let odometry = (position(&poses[j]) - position(&poses[j - 1])).norm();
            assert!(
                out <= odometry + 1e-9,
                "pose {j}: {out} m against {odometry} m"
            );
        }
    }

    // An odometry that publishes faster than it updates repeats its last estimate: every pose
    // published twice is corrected as once, each repeat answered as its first (and is no stall).
    let twice: Vec<Pose3> = drive.odom.iter().flat_map(|&p| [p, p]).collect();
    let repeated = correct(watched, &twice);
    for (i, c) in without_stops.iter().enumerate() {
        assert_eq!(repeated[2 * i].pose, c.pose, "pose {i}");
        assert_eq!(repeated[2 * i].status, c.status, "pose {i}");
        assert_eq!(repeated[2 * i + 1].pose, c.pose, "pose {i}, repeated");
    }
    let once = |out: &[CorrectedPose]| out.iter().step_by(2).map(|c| c.pose).collect::<Vec<_>>();
    let repeats_off = drive.ape(&once(&correct(off, &twice)));
    println!("every pose twice: {none:.3} m; with standstill_speed_mps = 0 {repeats_off:.3} m");
    assert!(
        repeats_off > none + 0.05,
        "the repeats matter without the setting"
    );
}

/// An odometry that jumps (restarted at its origin mid-drive; a SLAM system relocalising 25 m
/// and 30 degrees away) goes on publishing in another frame. Taken for road, the jump put every
/// later corrected pose where the new frame lies on the map (KITTI 00: 170 m mean APE-2D after a
/// restart at pose 2000). The jumps are flagged and the drive continues where it was.
#[test]
fn an_odometry_that_jumps_is_continued_where_the_vehicle_was() {
    let Some(data) = shared_data() else { return };
    let drive = Drive00::load(&data);
    let cam = Drive00::CAM;
    let (restart, relocalised) = (1500, 3000);
    let at_restart = cam.to_planar(&drive.odom[restart]).to_se2().inverse();
    let relocalisation = Se2::new(30f64.to_radians(), 25.0, -10.0);
    let poses: Vec<Pose3> = drive
        .odom
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let mut planar = cam.to_planar(p);
            if i >= restart {
                planar = apply_planar_correction(&at_restart, &planar);
            }
            if i >= relocalised {
                planar = apply_planar_correction(&relocalisation, &planar);
            }
            cam.from_planar(&planar)
        })
        .collect();
    let params = Drive00::params();
    let correct = |params, poses: &[Pose3]| drive.correct(params, poses);
    let ape = |out: &[CorrectedPose]| drive.ape(&out.iter().map(|c| c.pose).collect::<Vec<_>>());
    let unbroken = correct(params, &drive.odom);
    let jumped = correct(params, &poses);
    let flagged: Vec<usize> = (0..poses.len())
        .filter(|&i| matches!(jumped[i].status, Status::OdometryJump { .. }))
        .collect();
    assert_eq!(flagged, [restart, relocalised]);
    assert_eq!(jumped[..restart], unbroken[..restart]);
    // Where the vehicle was: the jumped pose one step of the last motion on, the correction in
    // force; its map_from_odom carries the odometry's new frame onto the map.
    let position = |p: &Pose3| cam.to_planar(p).planar_position();
    for &i in &flagged {
        let [x, y] = position(&jumped[i].pose);
        let [ux, uy] = position(&unbroken[i].pose);
        assert!(
            (x - ux).hypot(y - uy) < 0.5,
            "pose {i}: {x}, {y} against {ux}, {uy}"
        );
        let in_map = jumped[i].map_from_odom.apply(position(&poses[i]));
        let expected = (unbroken[i].map_from_odom).apply(position(&drive.odom[i]));
        let off = (in_map[0] - expected[0]).hypot(in_map[1] - expected[1]);
        assert!(off < 0.5, "pose {i}: map_from_odom {off} m off");
    }
    let mut off = params;
    off.max_speed_mps = f64::INFINITY;
    let (on, none, taken_for_road) = (ape(&jumped), ape(&unbroken), ape(&correct(off, &poses)));
    println!(
        "KITTI 00 lidar, restarted at pose {restart}, relocalised at {relocalised}: {on:.3} m \
         ({none:.3} m unbroken); jumps taken for road {taken_for_road:.3} m"
    );
    assert!((on - none).abs() < 0.15, "{on} m against {none} m");
    assert!(taken_for_road > 10.0, "the jumps matter without the check");
}

/// An odometry that glitches: one pose in ten from pose 100 on is published 500 m off its drive
/// (a corrupt message, a registration that failed and was mended on the next scan), off to the
/// side or ahead, where without stamps it reads as poses missing. The pose after each glitch
/// continues the drive from the pose before it, in the frame it had. Before, the pose after a
/// glitch jumped too, into a frame moved by the prediction's error, and one after a glitch
/// ahead jumped back 500 m: KITTI 00 so glitched came out at 2460 m mean APE-2D (and before that
/// frame was renormalised at each jump, its later poses scaled by 1e39, their rotations no
/// rotations).
#[test]
fn an_odometry_that_glitches_is_corrected_as_if_it_had_not() {
    let Some(data) = shared_data() else { return };
    let drive = Drive00::load(&data);
    let cam = Drive00::CAM;
    let params = Drive00::params();
    let unbroken = drive.correct(params, &drive.odom);
    let on_the_drive = |out: &[CorrectedPose], glitched: &dyn Fn(usize) -> bool| {
        let kept: Vec<usize> = (0..out.len()).filter(|&i| !glitched(i)).collect();
        let poses: Vec<Pose3> = kept
            .iter()
            .map(|&i| Drive00::CAM.to_planar(&out[i].pose))
            .collect();
        let gt: Vec<Pose3> = kept.iter().map(|&i| drive.gt[i]).collect();
        ape_2d(&gt, &poses).unwrap().mean_m
    };
    let none = on_the_drive(&unbroken, &|_| false);
    // Every tenth pose, ahead or off to the side; and every other pose, where the drive's step
    // is known only from the poses around each glitch. Without stamps, a glitch that lands
    // straight ahead (500 m along x where the car drives along x) reads as poses missing; with
    // stamps at the rate every glitch is a jump.
    for (off, every, bound, stamped) in [
        (Se2::new(0.0, 500.0, 0.0), 10, 0.1, false),
        (Se2::new(0.0, 500.0, 0.0), 10, 0.1, true),
        (Se2::new(0.0, -300.0, 400.0), 10, 0.1, false),
        (Se2::new(0.0, -300.0, 400.0), 2, 0.25, false),
    ] {
        let glitched = |i: usize| i >= 100 && i % every == every / 2;
        let poses: Vec<Pose3> = drive
            .odom
            .iter()
            .enumerate()
            .map(|(i, p)| match glitched(i) {
                true => cam.from_planar(&apply_planar_correction(&off, &cam.to_planar(p))),
                false => *p,
            })
            .collect();
        let stamps: Vec<f64> = (0..poses.len()).map(|i| i as f64 / 10.0).collect();
        let out = match stamped {
            false => drive.correct(params, &poses),
            true => drive.correct_stamped(params, &poses, &stamps),
        };
        let worst_rotation = out
            .iter()
            .map(|c| c.pose.rotation_error())
            .fold(0.0, f64::max);
        assert!(
            worst_rotation < 1e-9,
            "{off:?}: rotation error {worst_rotation}"
        );
        let flagged = (0..out.len())
            .filter(|&i| matches!(out[i].status, Status::OdometryJump { .. }))
            .count();
        let glitches = (0..out.len()).filter(|&i| glitched(i)).count();
        let on = on_the_drive(&out, &glitched);
        let all = on_the_drive(&out, &|_| false);
        println!(
            "KITTI 00 lidar, {glitches} poses glitched by {:?} (stamped: {stamped}): {flagged} \
             jumps, {on:.3} m on the other poses ({none:.3} m unglitched), {all:.3} m on all",
            off.translation()
        );
        assert!(
            flagged > glitches / 4 && flagged <= glitches,
            "{flagged} of {glitches}"
        );
        if stamped {
            assert_eq!(flagged, glitches, "stamped: every glitch is a jump");
        }
        // A glitch taken for poses missing is answered where the odometry put it, 500 m off:
        // its published covariance says so (the pose inside its 95 % ellipse).
        let odom_from_map = drive.placement.anchored_from_odom.inverse();
        let far: Vec<usize> = (0..out.len())
            .filter(|&i| {
                let est = cam.to_planar(&out[i].pose).planar_position();
                distance(est, drive.gt[i].planar_position()) > 50.0
            })
            .collect();
        println!("  {} poses more than 50 m off", far.len());
        assert_eq!(
            far.len(),
            glitches - flagged,
            "the glitches not taken for jumps"
        );
        if !far.is_empty() {
            let pick = |v: &[Pose3]| far.iter().map(|&i| v[i]).collect::<Vec<_>>();
            let est: Vec<Pose3> = out.iter().map(|c| cam.to_planar(&c.pose)).collect();
            let cov: Vec<[[f64; 2]; 2]> = far
                .iter()
                .map(|&i| position_covariance_in(&odom_from_map, &out[i].covariance))
                .collect();
            let far_off = calibration(&pick(&drive.gt), &pick(&est), &cov).unwrap();
            assert_eq!(far_off.cov95_coverage, 1.0, "{far_off:?}");
        }
        assert!((on - none).abs() < bound, "{on} m against {none} m");
    }
}

/// An odometry that loses track for a second writes no poses meanwhile, and a file without
/// stamps does not say how long the gap took. KITTI 00's LiDAR odometry with ten poses missing
/// every 500: the steps over the gaps are longer than the speed limit allows in one period, but
/// each drives on as the step before did, and is motion. Taken for jumps, each gap's road was lost.
#[test]
fn poses_missing_from_a_file_without_stamps_are_motion() {
    let Some(data) = shared_data() else { return };
    let drive = Drive00::load(&data);
    let kept: Vec<usize> = (0..drive.odom.len())
        .filter(|&i| i == 0 || i % 500 >= 10)
        .collect();
    let poses: Vec<Pose3> = kept.iter().map(|&i| drive.odom[i]).collect();
    let params = Drive00::params();
    // Not vacuous: most gaps are past the limit of one period.
    let position = |p: &Pose3| Drive00::CAM.to_planar(p).planar_position();
    let past_the_limit = poses
        .windows(2)
        .filter(|w| {
            let ([ax, ay], [bx, by]) = (position(&w[0]), position(&w[1]));
            (bx - ax).hypot(by - ay) > params.max_speed_mps / params.odometry_rate_hz
        })
        .count();
    assert!(past_the_limit >= 5, "{past_the_limit} steps past the limit");
    let out = drive.correct(params, &poses);
    let jumps = out
        .iter()
        .filter(|c| matches!(c.status, Status::OdometryJump { .. }))
        .count();
    assert_eq!(jumps, 0);
    let gt: Vec<Pose3> = kept.iter().map(|&i| drive.gt[i]).collect();
    let est: Vec<Pose3> = out
        .iter()
        .map(|c| Drive00::CAM.to_planar(&c.pose))
        .collect();
    let missing = ape_2d(&gt, &est).unwrap().mean_m;
    let unbroken = drive.correct(params, &drive.odom);
    let none = drive.ape(&unbroken.iter().map(|c| c.pose).collect::<Vec<_>>());
    println!(
        "KITTI 00 lidar, ten poses missing every 500 ({past_the_limit} steps past the limit): \
         {missing:.3} m ({none:.3} m with every pose)"
    );
    assert!((missing - none).abs() < 0.1, "{missing} m against {none} m");
}

/// A daemon session's poses are checked for their axes as they come
/// ([`plausibility::SourceWatch`], from 60 m of path on): on every shared run (ground truth,
/// LiDAR and visual odometry) they move as a vehicle does in the KITTI camera's axes; read as
/// `flu` they are told, naming the camera's frame, within 100 m, on all but the ground truth of
/// 08, which rises as the car sets off and then turns away from its start's forward axis: it is
/// told at 300 m, where its tilt is judged (until 2026-11-29 it was not told at all).
#[test]
fn a_sessions_poses_tell_its_axes_on_every_shared_run() {
    let Some(data) = shared_data() else { return };
    for run in ["kitti/poses", "odometry/lidar", "odometry/stereo_vo"] {
        for seq in SEQUENCES {
            let poses = read(&data.join(format!("{run}/{seq}.txt")), Format::Kitti)
                .unwrap()
                .poses;
            let told_by_its_tilt = (run, seq) == ("kitti/poses", "08");
            for (convention, told) in [
                (AxisConvention::KittiCamera, false),
                (AxisConvention::Flu, true),
            ] {
                let mut watch = plausibility::SourceWatch::new(10.0, 70.0, convention);
                let warnings: Vec<(usize, String)> = poses
                    .iter()
                    .enumerate()
                    .filter_map(|(i, p)| Some((i, watch.observe(0.1 * i as f64, p).axis_warning?)))
                    .collect();
                assert_eq!(
                    warnings.len(),
                    usize::from(told),
                    "{run} {seq} {convention:?}: {warnings:?}"
                );
                if let Some((i, w)) = warnings.first() {
                    assert!(w.contains("--frame kitti-camera"), "{run} {seq}: {w}");
                    let driven_m: f64 = poses[..=*i]
                        .windows(2)
                        .map(|p| (p[1].translation - p[0].translation).norm())
                        .sum();
                    let by_m = if told_by_its_tilt { 302.0 } else { 100.0 };
                    assert!(driven_m <= by_m, "{run} {seq}: told after {driven_m} m");
                }
            }
        }
    }
}

/// A daemon session's pace ([`plausibility::SourceWatch`]: the median speed of its first 50
/// steps that move) is a vehicle's on every shared run (ground truth, LiDAR and visual odometry),
/// and the changes of speed it tells are those `correct` finds in the file (the stall of the
/// visual odometry of 01 only). The same poses in centimetres are told once, by their pace, and
/// none of their changes of speed, 100 times steeper than a car's, is told.
#[test]
fn a_sessions_pace_is_a_vehicles_on_every_shared_run_and_centimetres_are_told() {
    let Some(data) = shared_data() else { return };
    let cam = AxisConvention::KittiCamera;
    for run in ["kitti/poses", "odometry/lidar", "odometry/stereo_vo"] {
        for seq in SEQUENCES {
            let poses = read(&data.join(format!("{run}/{seq}.txt")), Format::Kitti)
                .unwrap()
                .poses;
            let centimetres: Vec<Pose3> = poses
                .iter()
                .map(|p| Pose3 {
                    translation: p.translation * 100.0,
                    ..*p
                })
                .collect();
            let watched = |poses: &[Pose3]| {
                let mut watch = plausibility::SourceWatch::new(10.0, 70.0, cam);
                let mut news: Vec<_> = poses
                    .iter()
                    .enumerate()
                    .map(|(i, p)| watch.observe(0.1 * i as f64, p))
                    .collect();
                news.push(watch.finish());
                let paces: Vec<String> =
                    news.iter().filter_map(|n| n.pace_warning.clone()).collect();
                let changes = news.iter().map(|n| n.speed_changes.len()).sum::<usize>();
                (paces, changes)
            };
            let planar: Vec<[f64; 2]> = poses
                .iter()
                .map(|p| cam.to_planar(p).planar_position())
                .collect();
            let in_the_file = plausibility::speed_changes(&planar, 10.0).len();
            assert_eq!(watched(&poses), (vec![], in_the_file), "{run} {seq}");
            let (paces, changes) = watched(&centimetres);
            assert_eq!((paces.len(), changes), (1, 0), "{run} {seq}: {paces:?}");
            assert!(
                paces[0].contains("are its positions in metres"),
                "{run} {seq}: {paces:?}"
            );
        }
    }
}

/// The visual odometry of sequence 01 loses track on the highway: its speed falls from 20 to
/// about 1 m/s in under a second near pose 806 while the car drives on at 22 m/s, and it misses
/// some 80 m of road, which the straight highway's lanes cannot show. `correct` warns of it
/// ([`plausibility::speed_change_warning`]); no other shared run (ground truth, LiDAR or visual
/// odometry) changes speed faster than a car can, nor LiDAR 00 with poses missing from the file
/// or resampled to 100 Hz.
#[test]
fn a_visual_odometry_that_stalls_is_noticed_and_no_other_run_is() {
    let Some(data) = shared_data() else { return };
    let cam = AxisConvention::KittiCamera;
    let positions = |poses: &[Pose3]| -> Vec<[f64; 2]> {
        poses
            .iter()
            .map(|p| cam.to_planar(p).planar_position())
            .collect()
    };
    for run in ["kitti/poses", "odometry/lidar", "odometry/stereo_vo"] {
        for seq in SEQUENCES {
            let poses = read(&data.join(format!("{run}/{seq}.txt")), Format::Kitti)
                .unwrap()
                .poses;
            let changes = plausibility::speed_changes(&positions(&poses), 10.0);
            if (run, seq) != ("odometry/stereo_vo", "01") {
                assert!(changes.is_empty(), "{run} {seq}: {changes:?}");
                assert!(plausibility::speed_change_warning(&poses, cam, 10.0).is_none());
                continue;
            }
            let stall = changes
                .iter()
                .find(|c| (800..815).contains(&c.pose))
                .unwrap_or_else(|| panic!("{changes:?}"));
            assert!(stall.from_mps > 15.0 && stall.to_mps < 5.0, "{stall:?}");
            // Where it recovers, it speeds up faster than a car can, too.
            assert!(
                changes.iter().any(|c| c.acceleration_mps2() > 10.0),
                "{changes:?}"
            );
            let warning = plausibility::speed_change_warning(&poses, cam, 10.0).unwrap();
            assert!(
                warning.contains(&format!("pose {}", stall.pose)),
                "{warning}"
            );
        }
    }
    let lidar = read(&data.join("odometry/lidar/00.txt"), Format::Kitti)
        .unwrap()
        .poses;
    let gappy: Vec<Pose3> = (0..lidar.len())
        .filter(|&i| i == 0 || i % 500 >= 10)
        .map(|i| lidar[i])
        .collect();
    assert_eq!(plausibility::speed_changes(&positions(&gappy), 10.0), []);
    let fast = positions(&ten_times_the_rate(&lidar));
    assert_eq!(plausibility::speed_changes(&fast, 100.0), []);
}

/// Where the visual odometry of 01 stalls (above), the corrector takes it to have driven on at
/// its speed before the stall: the window restarts, since the poses before and after the road
/// it missed are no longer one rigid piece, and the covariance widens along the road by the
/// distance it may have missed. The poses after the stall were off by 100 m and more while
/// their covariance said 6 m (mean NEES 213); now their errors lie within the covariance's 95 %
/// ellipse nearly everywhere. The drive's figures are then those of its first 806 poses, where
/// the odometry's scale is off on the highway (coverage 0.70, NEES 4.5 before the stall).
#[test]
fn a_stalled_visual_odometry_has_a_covariance_that_says_so() {
    let Some(data) = shared_data() else { return };
    let s = sequence(&data, "01");
    let params = Method::Robust.params(Preset::OrbSlam3);
    let unwatched = Params {
        watch_stalls: false,
        ..params
    };
    let (watched, est, cov) = run_with(&data, &s, "stereo_vo", Method::Robust, params, None);
    let (before, est_before, cov_before) =
        run_with(&data, &s, "stereo_vo", Method::Robust, unwatched, None);
    let gt: Vec<Pose3> =
        s.gt.iter()
            .map(|p| AxisConvention::KittiCamera.to_planar(p))
            .collect();
    let after_stall = |est: &[Pose3], cov: &[[[f64; 2]; 2]]| {
        calibration(&gt[806..], &est[806..], &cov[806..]).unwrap()
    };
    let (now, then) = (
        after_stall(&est, &cov),
        after_stall(&est_before, &cov_before),
    );
    println!(
        "stereo_vo 01 after the stall: coverage {:.3} -> {:.3}, NEES {:.2} -> {:.2}; whole \
         drive {:.3} -> {:.3}, NEES {:.2} -> {:.2}; APE-2D {:.3} -> {:.3} m",
        then.cov95_coverage,
        now.cov95_coverage,
        then.nees_mean,
        now.nees_mean,
        before.calibration.cov95_coverage,
        watched.calibration.cov95_coverage,
        before.calibration.nees_mean,
        watched.calibration.nees_mean,
        before.corrected.mean_m,
        watched.corrected.mean_m,
    );
    assert!(
        then.cov95_coverage < 0.05 && then.nees_mean > 100.0,
        "{then:?}"
    );
    assert!(now.cov95_coverage > 0.9 && now.nees_mean < 6.0, "{now:?}");
    assert!(
        watched.calibration.nees_mean < 6.0 && watched.calibration.cov95_coverage > 0.7,
        "{:?}",
        watched.calibration
    );
    // The corrections hardly change: what the odometry missed along the road, the lanes of a
    // straight road cannot show.
    assert!(
        (watched.corrected.mean_m - before.corrected.mean_m).abs() < 1.0,
        "{} against {} m",
        watched.corrected.mean_m,
        before.corrected.mean_m
    );
}

/// Where a drive turns: from a fifth of the way on, the first pose where ground truth (planar)
/// drives faster than 6 m/s and turns by at least 30 degrees over the next 3 s (30 poses); then
/// the next one 300 poses on, up to 130 poses before the end.
fn turns(gt: &[Pose3]) -> Vec<usize> {
    let mut found = Vec::new();
    let mut i = gt.len() / 5;
    while i + 130 < gt.len() {
        let speed_mps = 10.0 * distance(gt[i].planar_position(), gt[i + 1].planar_position());
        let turned = wrap_angle(gt[i + 30].planar_heading() - gt[i].planar_heading());
        if speed_mps > 6.0 && turned.abs() >= 30f64.to_radians() {
            found.push(i);
            i += 300;
        } else {
            i += 1;
        }
    }
    found
}

/// `odom` (KITTI's camera convention) frozen at pose `from` for `count` poses, as a visual
/// odometry that loses track: it repeats that pose, then goes on with its own motion from
/// there. The motion it missed, the turn included, is lost.
fn frozen(odom: &[Pose3], from: usize, count: usize) -> Vec<Pose3> {
    let cam = AxisConvention::KittiCamera;
    let at = |i: usize| cam.to_planar(&odom[i]).to_se2();
    let resumed = at(from) * at(from + count).inverse();
    odom.iter()
        .enumerate()
        .map(|(i, pose)| match i {
            i if i <= from => *pose,
            i if i < from + count => odom[from],
            _ => cam.from_planar(&apply_planar_correction(&resumed, &cam.to_planar(pose))),
        })
        .collect()
}

/// An odometry that freezes for 3 s in a turn (every turn of every sequence that [`turns`]
/// finds, on both runs) misses the turn: its heading is off by 30 degrees and more when it
/// goes on. The stall watch widens the heading's uncertainty by what a car may turn over the
/// road missed, so the published heading covers the error it left, and the position's
/// covariance grows as that heading error turns into position error.
#[test]
fn an_odometry_frozen_in_a_turn_has_a_heading_covariance_that_says_so() {
    let Some(data) = shared_data() else { return };
    let cam = AxisConvention::KittiCamera;
    let mut cases = 0;
    let sequences = sequences(&data);
    for (odometry, preset) in [("lidar", Preset::KissIcp), ("stereo_vo", Preset::OrbSlam3)] {
        let mut nees = Vec::new();
        for s in &sequences {
            let gt: Vec<Pose3> = s.gt.iter().map(|p| cam.to_planar(p)).collect();
            let odom = odometry_of(&data, odometry, s);
            for from in turns(&gt) {
                let params = Method::Robust.params(preset);
                let Corrected {
                    est, cov, answers, ..
                } = run_poses(s, &frozen(&odom, from, 30), Method::Robust, params, None);
                let on = from + 31;
                let heading_error = wrap_angle(est[on].planar_heading() - gt[on].planar_heading());
                let heading_sd = answers[on].covariance[2][2].sqrt();
                let after = calibration(&gt[from..], &est[from..], &cov[from..]).unwrap();
                println!(
                    "{odometry} {} frozen at {from}: heading {:.1} deg off, sd {:.1} deg; after \
                     it coverage {:.3}, NEES {:.2}",
                    s.name,
                    heading_error.to_degrees(),
                    heading_sd.to_degrees(),
                    after.cov95_coverage,
                    after.nees_mean
                );
                assert!(heading_error.abs() > 25f64.to_radians());
                assert!(
                    heading_error.abs() < 2.0 * heading_sd,
                    "{odometry} {} at {from}: the heading {:.1} deg off, its sd {:.1} deg",
                    s.name,
                    heading_error.to_degrees(),
                    heading_sd.to_degrees()
                );
                nees.push(after.nees_mean);
                cases += 1;
            }
        }
        nees.sort_by(f64::total_cmp);
        let median = nees[nees.len() / 2];
        println!("{odometry}: median NEES after the freeze {median:.2}");
        assert!(median < 60.0, "{odometry}: median NEES {median}");
    }
    assert!(cases >= 60, "{cases} turns");
}
