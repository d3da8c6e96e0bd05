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
    /// The corrected pose, in the input's frame and axis convention.
    pub pose: Pose3,
    /// The correction in force after this pose: maps planar odometry coordinates onto the lane
    /// map's plane (the anchor placement composed with the accumulated correction).
    pub map_from_odom: Se2,
    /// What the corrector did.
    pub status: Status,
}

/// How a source's poses are read and placed on the lane map.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Source {
    /// The poses' axis convention.
    pub convention: AxisConvention,
    /// Where the source's planar odometry frame lies in the map plane (from its anchor;
    /// the identity when the lanes are already in the odometry frame).
    pub plane_from_odom: Se2,
}

/// Corrects `poses` against `map`: each pose is moved into the map plane, corrected there, and
/// moved back, so the output is in the input's own frame and convention.
pub fn correct(
    map: Arc<LaneMap>,
    params: Params,
    mode: MatchMode,
    source: Source,
    poses: &[Pose3],
) -> Vec<CorrectedPose> {
    let mut corrector = Corrector::with_mode(map, params, mode);
    let odom_from_plane = source.plane_from_odom.inverse();
    poses
        .iter()
        .map(|pose| {
            let in_plane = apply_planar_correction(
                &source.plane_from_odom,
                &source.convention.to_planar(pose),
            );
            let step = corrector.push(planar_position(&in_plane));
            let corrected = match step.status {
                Status::InvalidInput => *pose,
                _ => {
                    let corrected_in_plane =
                        apply_planar_correction(&step.map_from_odom, &in_plane);
                    source.convention.from_planar(&apply_planar_correction(
                        &odom_from_plane,
                        &corrected_in_plane,
                    ))
                }
            };
            CorrectedPose {
                pose: corrected,
                map_from_odom: step.map_from_odom * source.plane_from_odom,
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
