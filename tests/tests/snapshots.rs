//! Every state a session passes through on the real runs is one its journal's snapshot keeps and
//! a restarted daemon restores: the checks a restore makes of a snapshot (positions within reach,
//! covariances a filter continues from, a plausible scale and rate) refuse only snapshots
//! tampered with. Visual odometry with the orb-slam3 preset (its scale estimated, its stalls
//! watched) on 00 and on 01, whose odometry stalls on the highway, and LiDAR odometry with the
//! kiss-icp preset on 00.

use lanealign_cli::maps::MapSource;
use lanealign_core::corrector::MatchMode;
use lanealign_core::geo::Projection;
use lanealign_core::params::{Method, Params, Preset, MAX_ODOMETRY_RATE_HZ, MIN_ODOMETRY_RATE_HZ};
use lanealign_core::pose::AxisConvention;
use lanealign_core::scale::MAX_SCALE_DRIFT_VAR_PER_M;
use lanealign_core::source_corrector::{Placement, SourceCorrector};
use lanealign_core::trajectory::{read, Format};
use lanealign_map::osm_lanes::LaneOptions;
use lanealign_service::journal::Snapshot;
use lanealign_tests::{kitti_anchor, shared_data};

#[test]
fn every_state_of_a_real_run_is_saved_and_restored() {
    let Some(data) = shared_data() else { return };
    for (odometry, preset, name) in [
        ("stereo_vo", Preset::OrbSlam3, "00"),
        ("stereo_vo", Preset::OrbSlam3, "01"),
        ("lidar", Preset::KissIcp, "00"),
    ] {
        let loaded = MapSource::Osm {
            path: data.join(format!("osm/kitti_{name}.osm")),
            anchor: kitti_anchor(&data, name),
            projection: Projection::Kitti,
            options: LaneOptions::for_method(Method::Robust),
        }
        .load()
        .unwrap();
        let placement = Placement {
            convention: AxisConvention::KittiCamera,
            anchored_from_odom: loaded.anchored_from_odom,
            smoothing: None,
        };
        let mut corrector = SourceCorrector::new(
            loaded.map.clone(),
            Method::Robust.params(preset),
            MatchMode::Fast,
            placement,
        );
        let poses = read(
            &data.join(format!("odometry/{odometry}/{name}.txt")),
            Format::Kitti,
        )
        .unwrap()
        .poses;
        for (i, pose) in poses.iter().enumerate() {
            corrector.correct(pose);
            let saved = Snapshot {
                last_seq: i as u64 + 1,
                next_segment: 1,
                state: corrector.state(),
                watch: None,
            }
            .encode();
            let restored = Snapshot::decode(&saved).map(|s| s.encode());
            assert!(
                restored.as_ref() == Some(&saved),
                "{odometry} {name}, pose {i}: {:?}",
                corrector.state()
            );
        }
    }
}

/// The same with every parameter that bounds a covariance's growth or a gate at the ends of what
/// a configuration may set (one at a time, on the preset that uses it): each answer's pose,
/// covariance and scale are finite, and every state is one a restarted daemon restores. Visual
/// odometry on 01 (the highway, where it stalls: long stretches whose lanes say nothing along the
/// road, so that covariances grow the most).
#[test]
fn every_state_restores_with_parameters_at_their_bounds() {
    let Some(data) = shared_data() else { return };
    let name = "01";
    let loaded = MapSource::Osm {
        path: data.join(format!("osm/kitti_{name}.osm")),
        anchor: kitti_anchor(&data, name),
        projection: Projection::Kitti,
        options: LaneOptions::for_method(Method::Robust),
    }
    .load()
    .unwrap();
    let placement = Placement {
        convention: AxisConvention::KittiCamera,
        anchored_from_odom: loaded.anchored_from_odom,
        smoothing: None,
    };
    let poses = read(
        &data.join(format!("odometry/stereo_vo/{name}.txt")),
        Format::Kitti,
    )
    .unwrap()
    .poses;
    let set = |f: fn(&mut Params)| -> Params {
        let mut p = Method::Robust.params(Preset::OrbSlam3);
        f(&mut p);
        p
    };
    let bounds: [(&str, Params); 14] = [
        (
            "drift_var_per_m near 1e6",
            set(|p| p.drift_var_per_m = 999_999.0),
        ),
        (
            "yaw_drift_var_per_m near 1e6",
            set(|p| p.yaw_drift_var_per_m = 999_999.0),
        ),
        (
            "initial_sigma_m near 1e6",
            set(|p| p.initial_sigma_m = 999_999.0),
        ),
        (
            "initial_sigma_yaw_deg near 1e6",
            set(|p| p.initial_sigma_yaw_deg = 999_999.0),
        ),
        (
            "drift variances of 1e-300",
            set(|p| {
                p.drift_var_per_m = 1e-300;
                p.yaw_drift_var_per_m = 1e-300;
                p.initial_sigma_m = 1e-300;
                p.initial_sigma_yaw_deg = 1e-300;
            }),
        ),
        (
            "scale at its bounds",
            set(|p| {
                p.scale_sigma = 0.5;
                p.scale_drift_var_per_m = MAX_SCALE_DRIFT_VAR_PER_M;
            }),
        ),
        ("drift_per_m 1e300", set(|p| p.drift_per_m = 1e300)),
        ("no gate", set(|p| p.max_match_distance_m = f64::INFINITY)),
        (
            "lane_tolerance_m 1e300",
            set(|p| p.lane_tolerance_m = 1e300),
        ),
        ("max_residual_m 1e300", set(|p| p.max_residual_m = 1e300)),
        (
            "min_evidence_ratio 1e300",
            set(|p| p.min_evidence_ratio = 1e300),
        ),
        ("icp_tolerance_m 1e300", set(|p| p.icp_tolerance_m = 1e300)),
        (
            "odometry_rate_hz 1e-3",
            set(|p| p.odometry_rate_hz = MIN_ODOMETRY_RATE_HZ),
        ),
        (
            "odometry_rate_hz 1e5",
            set(|p| p.odometry_rate_hz = MAX_ODOMETRY_RATE_HZ),
        ),
    ];
    for (what, params) in bounds {
        params.validate().unwrap_or_else(|e| panic!("{what}: {e}"));
        let mut corrector =
            SourceCorrector::new(loaded.map.clone(), params, MatchMode::Fast, placement);
        for (i, pose) in poses.iter().enumerate() {
            let (answer, _) = corrector.correct(pose);
            let finite = answer.pose.is_finite()
                && answer.covariance.iter().flatten().all(|v| v.is_finite())
                && answer.odometry_scale.is_finite()
                && answer.odometry_scale_sd.is_finite();
            assert!(finite, "{what}, pose {i}: {answer:?}");
            let saved = Snapshot {
                last_seq: i as u64 + 1,
                next_segment: 1,
                state: corrector.state(),
                watch: None,
            }
            .encode();
            let restored = Snapshot::decode(&saved).map(|s| s.encode());
            assert!(
                restored.as_ref() == Some(&saved),
                "{what}, pose {i}: {:?}",
                corrector.state()
            );
        }
    }
}
