//! Correcting a whole recorded trajectory at once, pose by pose, exactly as the online corrector
//! would have seen it.

use std::sync::Arc;

use crate::corrector::{Corrector, MatchMode, Status, StepTiming};
use crate::lane_map::LaneMap;
use crate::params::Params;
use crate::pose::{apply_planar_correction, planar_position, AxisConvention, Pose3};
use crate::se2::Se2;
use crate::smoothing::{Smoother, Smoothing};

/// The per-pose record of an offline correction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CorrectedPose {
    /// The corrected pose, in the input's frame and axis convention (smoothed when the source
    /// asks for smooth output).
    pub pose: Pose3,
    /// The exact correction in force after this pose, never smoothed: maps planar odometry
    /// coordinates onto the lane map's plane (the anchor placement composed with the accumulated
    /// correction).
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
    /// Publish smoothed poses within these limits instead of the exact ones (see
    /// [`crate::smoothing`]); `None` publishes the exact correction.
    pub smoothing: Option<Smoothing>,
}

/// One source's corrector with its placement: takes poses in the source's own frame and
/// convention and returns them corrected in the same. The daemon runs one per source; offline
/// correction runs one over a whole file, so both give the same answers.
pub struct SourceCorrector {
    corrector: Corrector,
    source: Source,
    odom_from_plane: Se2,
    smoother: Option<Smoother>,
}

impl SourceCorrector {
    /// A corrector for `source` on `map`.
    pub fn new(map: Arc<LaneMap>, params: Params, mode: MatchMode, source: Source) -> Self {
        SourceCorrector {
            corrector: Corrector::with_mode(map, params, mode),
            odom_from_plane: source.plane_from_odom.inverse(),
            smoother: source.smoothing.map(Smoother::new),
            source,
        }
    }

    /// Corrects the next pose; returns the step's timing too.
    pub fn correct(&mut self, pose: &Pose3) -> (CorrectedPose, StepTiming) {
        let source = &self.source;
        let in_plane =
            apply_planar_correction(&source.plane_from_odom, &source.convention.to_planar(pose));
        let step = self.corrector.push(planar_position(&in_plane));
        let corrected = match step.status {
            Status::InvalidInput => *pose,
            _ => {
                let published = match &mut self.smoother {
                    Some(smoother) => smoother.next(step.map_from_odom, planar_position(&in_plane)),
                    None => step.map_from_odom,
                };
                let corrected_in_plane = apply_planar_correction(&published, &in_plane);
                source.convention.from_planar(&apply_planar_correction(
                    &self.odom_from_plane,
                    &corrected_in_plane,
                ))
            }
        };
        let record = CorrectedPose {
            pose: corrected,
            map_from_odom: step.map_from_odom * source.plane_from_odom,
            status: step.status,
        };
        (record, step.timing)
    }
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
    let mut corrector = SourceCorrector::new(map, params, mode, source);
    poses.iter().map(|pose| corrector.correct(pose).0).collect()
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
