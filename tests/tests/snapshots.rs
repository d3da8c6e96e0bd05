//! Every state a session passes through on the real runs is one its journal's snapshot keeps and
//! a restarted daemon restores: the checks a restore makes of a snapshot (positions within reach,
//! covariances a filter continues from, a plausible scale and rate) refuse only snapshots
//! tampered with. Visual odometry with the orb-slam3 preset (its scale estimated, its stalls
//! watched) on 00 and on 01, whose odometry stalls on the highway, and LiDAR odometry with the
//! kiss-icp preset on 00.

use lanealign_cli::maps::MapSource;
use lanealign_core::corrector::MatchMode;
use lanealign_core::geo::Projection;
use lanealign_core::params::{Method, Preset};
use lanealign_core::pose::AxisConvention;
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
