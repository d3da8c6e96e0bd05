//! The fast matcher changes the work, never the answer: both match modes give the same status
//! sequence and the same corrected poses on real sequences.

use std::sync::Arc;

use lanealign_core::corrector::{MatchMode, Status};
use lanealign_core::lane_csv;
use lanealign_core::lane_map::LaneMap;
use lanealign_core::params::{Method, Preset};
use lanealign_core::pose::AxisConvention;
use lanealign_core::se2::{wrap_angle, Se2};
use lanealign_core::source_corrector::{
    correct_trajectory, CorrectedPose, Placement, SourceCorrector,
};
use lanealign_core::trajectory::{read, Format};
use lanealign_tests::shared_data;

#[test]
fn fast_and_reference_modes_agree_on_real_sequences() {
    let Some(data) = shared_data() else { return };
    let cam = AxisConvention::KittiCamera;
    let placement = Placement {
        convention: cam,
        anchored_from_odom: Se2::IDENTITY,
        smoothing: None,
    };
    for seq in ["04", "06", "07"] {
        let lanes = lane_csv::read(&data.join(format!("reference/lanes/lanes_{seq}.csv"))).unwrap();
        let map = Arc::new(LaneMap::new(&lanes).unwrap());
        for (odometry, preset, method) in [
            ("lidar", Preset::KissIcp, Method::Paper),
            ("stereo_vo", Preset::Basalt, Method::Paper),
            ("lidar", Preset::KissIcp, Method::Robust),
            ("stereo_vo", Preset::Basalt, Method::Robust),
        ] {
            let odom = read(
                &data.join(format!("odometry/{odometry}/{seq}.txt")),
                Format::Kitti,
            )
            .unwrap();
            let fast = correct_trajectory(
                map.clone(),
                method.params(preset),
                MatchMode::Fast,
                placement,
                &odom.poses,
            );
            let reference = correct_trajectory(
                map.clone(),
                method.params(preset),
                MatchMode::Reference,
                placement,
                &odom.poses,
            );
            let accepted = fast
                .iter()
                .filter(|c| matches!(c.status, Status::Accepted { .. }))
                .count();
            assert!(
                accepted > 50,
                "{odometry} {seq}: the comparison must exercise corrections"
            );
            for (i, (f, r)) in fast.iter().zip(&reference).enumerate() {
                assert_eq!(
                    f.status,
                    r.status,
                    "{odometry} {} {seq}: status differs at pose {i}",
                    preset.name()
                );
                let (pf, pr) = (cam.to_planar(&f.pose), cam.to_planar(&r.pose));
                assert!(
                    (pf.translation - pr.translation).amax() <= 1e-9,
                    "{odometry} {seq} pose {i}"
                );
                assert!(wrap_angle(pf.planar_heading() - pr.planar_heading()).abs() <= 1e-12);
            }
        }
    }
}

/// The daemon matches the window ahead between poses (`Corrector::work_ahead`); the answers are
/// those of a corrector that does not, bit for bit, on real sequences whose windows move on
/// most steps.
#[test]
fn matching_ahead_between_poses_changes_no_answer_on_real_sequences() {
    let Some(data) = shared_data() else { return };
    let placement = Placement {
        convention: AxisConvention::KittiCamera,
        anchored_from_odom: Se2::IDENTITY,
        smoothing: None,
    };
    let (mut moved_poses, mut poses) = (0, 0);
    for seq in ["00", "06", "07"] {
        let lanes = lane_csv::read(&data.join(format!("reference/lanes/lanes_{seq}.csv"))).unwrap();
        let map = Arc::new(LaneMap::new(&lanes).unwrap());
        for (odometry, preset) in [("lidar", Preset::KissIcp), ("stereo_vo", Preset::Basalt)] {
            let odom = read(
                &data.join(format!("odometry/{odometry}/{seq}.txt")),
                Format::Kitti,
            )
            .unwrap();
            let params = Method::Robust.params(preset);
            let unprepared =
                correct_trajectory(map.clone(), params, MatchMode::Fast, placement, &odom.poses);
            let mut corrector =
                SourceCorrector::new(map.clone(), params, MatchMode::Fast, placement);
            let prepared: Vec<CorrectedPose> = odom
                .poses
                .iter()
                .map(|pose| {
                    let (answer, _) = corrector.correct(pose);
                    corrector.prepare();
                    corrector.work_ahead();
                    answer
                })
                .collect();
            let moved = unprepared
                .windows(2)
                .filter(|w| w[0].map_from_odom != w[1].map_from_odom)
                .count();
            assert_eq!(prepared, unprepared, "{odometry} {seq}");
            moved_poses += moved;
            poses += odom.poses.len();
        }
    }
    assert!(
        moved_poses * 4 > poses,
        "the comparison must exercise moving windows: {moved_poses} of {poses} poses moved"
    );
}
