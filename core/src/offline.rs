//! Correcting a whole recorded trajectory at once, pose by pose, exactly as the online corrector
//! would have seen it.

use std::sync::Arc;

use crate::corrector::{Corrector, MatchMode, Status};
use crate::lane_map::LaneMap;
use crate::params::Params;
use crate::pose::{apply_planar_correction, planar_position, AxisConvention, Pose3};
use crate::se2::Se2;

/// The per-pose record of an offline correction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CorrectedPose {
    /// The corrected pose, in the input's axis convention.
    pub pose: Pose3,
    /// The correction in force after this pose (planar frame).
    pub map_from_odom: Se2,
    /// What the corrector did.
    pub status: Status,
}

/// Corrects `poses` (in `convention`) against `map`, whose plane is the source's planar
/// odometry frame after anchoring.
pub fn correct(
    map: Arc<LaneMap>,
    params: Params,
    mode: MatchMode,
    convention: AxisConvention,
    poses: &[Pose3],
) -> Vec<CorrectedPose> {
    let mut corrector = Corrector::with_mode(map, params, mode);
    poses
        .iter()
        .map(|pose| {
            let planar = convention.to_planar(pose);
            let step = corrector.push(planar_position(&planar));
            let corrected = match step.status {
                Status::InvalidInput => *pose,
                _ => convention.from_planar(&apply_planar_correction(&step.map_from_odom, &planar)),
            };
            CorrectedPose {
                pose: corrected,
                map_from_odom: step.map_from_odom,
                status: step.status,
            }
        })
        .collect()
}

/// Counts over a corrected run: `(match attempts, accepted, resets)`.
pub fn counts(run: &[CorrectedPose]) -> (usize, usize, usize) {
    let attempts = run.iter().filter(|c| c.status.attempted()).count();
    let accepted = run
        .iter()
        .filter(|c| matches!(c.status, Status::Accepted { .. }))
        .count();
    let resets = run
        .iter()
        .filter(|c| matches!(c.status, Status::Reset { .. }))
        .count();
    (attempts, accepted, resets)
}
