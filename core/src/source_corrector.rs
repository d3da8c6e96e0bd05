//! One source's corrector with its placement on the map: takes poses in the source's own frame
//! and axis convention and returns them corrected in the same. The daemon runs one per session;
//! [`correct_trajectory`] runs one over a whole recorded file, so both give the same answers.
//!
//! Frames: `odom` is the source's planar odometry frame (after its axis convention is turned
//! into `flu`); `anchored` is the map plane as the anchor places the odometry, before any
//! correction; `map` is the corrected map plane. `map_from_odom = map_from_anchored *
//! anchored_from_odom`.

use std::sync::Arc;

use crate::confidence::Covariance;
use crate::corrector::{Corrector, CorrectorState, MatchMode, Status, StepTiming};
use crate::lane_map::LaneMap;
use crate::params::Params;
use crate::pose::{apply_planar_correction, AxisConvention, Pose3};
use crate::se2::Se2;
use crate::smoothing::{Smoother, Smoothing};

/// The per-pose record of a correction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CorrectedPose {
    /// The corrected pose, in the input's frame and axis convention (smoothed when the source
    /// asks for smooth output; the input unchanged for invalid input).
    pub pose: Pose3,
    /// The exact correction in force after this pose, never smoothed: maps planar odometry
    /// coordinates onto the corrected map plane (the anchor's placement composed with the
    /// accumulated correction).
    pub map_from_odom: Se2,
    /// The covariance of the exact corrected pose's error (map plane; x, y in metres, yaw in
    /// radians; see [`crate::confidence`]).
    pub covariance: Covariance,
    /// What the corrector did.
    pub status: Status,
}

/// How a source's poses are read and placed on the lane map.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    /// The poses' axis convention.
    pub convention: AxisConvention,
    /// Where the anchor places the source's planar odometry frame in the map plane (the
    /// identity when the lanes are already in the odometry frame).
    pub anchored_from_odom: Se2,
    /// Publish smoothed poses within these limits instead of the exact ones (see
    /// [`crate::smoothing`]); `None` publishes the exact correction.
    pub smoothing: Option<Smoothing>,
}

impl Placement {
    /// Where the anchor places `pose` (the source's convention) in the map plane, before any
    /// correction (metres, frame `anchored`).
    pub fn position_in_anchored(&self, pose: &Pose3) -> [f64; 2] {
        self.anchored_from_odom
            .apply(self.convention.to_planar(pose).planar_position())
    }
}

/// Everything a source corrector's future answers depend on (see [`CorrectorState`]).
#[derive(Clone, Debug, PartialEq)]
pub struct SourceState {
    /// The corrector's state.
    pub corrector: CorrectorState,
    /// The last published (smoothed) correction, when the source smooths.
    pub smoothed: Option<Se2>,
}

/// A corrector for one source: converts, places, corrects and converts back.
pub struct SourceCorrector {
    corrector: Corrector,
    placement: Placement,
    odom_from_anchored: Se2,
    anchor_yaw: f64,
    smoother: Option<Smoother>,
}

impl SourceCorrector {
    /// A corrector for a source placed by `placement` on `map`. `params` must pass
    /// [`Params::validate`].
    pub fn new(map: Arc<LaneMap>, params: Params, mode: MatchMode, placement: Placement) -> Self {
        SourceCorrector {
            corrector: Corrector::with_mode(map, params, mode),
            odom_from_anchored: placement.anchored_from_odom.inverse(),
            anchor_yaw: placement.anchored_from_odom.yaw(),
            smoother: placement.smoothing.map(Smoother::new),
            placement,
        }
    }

    /// The rotation of the source's anchor (radians): its planar odometry frame turned into the
    /// map plane before any correction.
    pub fn anchor_yaw(&self) -> f64 {
        self.anchor_yaw
    }

    /// Poses in the corrector's window.
    pub fn window_len(&self) -> usize {
        self.corrector.window().len()
    }

    /// The corrector's window: corrected positions, oldest first (metres, map plane).
    pub fn window(&self) -> &[[f64; 2]] {
        self.corrector.window()
    }

    /// Where `pose` would lie in the map plane under the correction in force (metres): the
    /// position the next step queries around.
    pub fn predicted_position_in_map(&self, pose: &Pose3) -> [f64; 2] {
        self.corrector
            .map_from_anchored()
            .apply(self.placement.position_in_anchored(pose))
    }

    /// The lane map in use.
    pub fn map(&self) -> &Arc<LaneMap> {
        self.corrector.map()
    }

    /// Continues on another lane map (see [`Corrector::replace_map`]).
    pub fn replace_map(&mut self, map: Arc<LaneMap>) {
        self.corrector.replace_map(map);
    }

    /// The state to continue from later.
    pub fn state(&self) -> SourceState {
        SourceState {
            corrector: self.corrector.state(),
            smoothed: self.smoother.as_ref().and_then(Smoother::output_from_odom),
        }
    }

    /// A source corrector that continues from `state`, exactly as the saved one would.
    pub fn restore(
        map: Arc<LaneMap>,
        params: Params,
        mode: MatchMode,
        placement: Placement,
        state: SourceState,
    ) -> Self {
        SourceCorrector {
            corrector: Corrector::restore(map, params, mode, state.corrector),
            odom_from_anchored: placement.anchored_from_odom.inverse(),
            anchor_yaw: placement.anchored_from_odom.yaw(),
            smoother: placement
                .smoothing
                .map(|limits| Smoother::restore(limits, state.smoothed)),
            placement,
        }
    }

    /// Readies the memory the next [`SourceCorrector::correct`] may need, off the latency
    /// path ([`Corrector::prepare`]).
    pub fn prepare(&mut self) {
        self.corrector.prepare();
    }

    /// Does the part of the next [`SourceCorrector::correct`] that needs no pose, off the
    /// latency path ([`Corrector::work_ahead`]).
    pub fn work_ahead(&mut self) {
        self.corrector.work_ahead();
    }

    /// Corrects the next pose (`world_from_body` in the source's convention); returns the
    /// step's timing too. A pose that is no pose ([`Pose3::problem`]: a non-finite number, an
    /// absurd coordinate, a rotation that is not one) is answered as invalid input and changes
    /// nothing.
    pub fn correct(&mut self, pose: &Pose3) -> (CorrectedPose, StepTiming) {
        if pose.problem().is_some() {
            let record = CorrectedPose {
                pose: *pose,
                map_from_odom: self.corrector.map_from_anchored()
                    * self.placement.anchored_from_odom,
                covariance: self.corrector.covariance(),
                status: Status::InvalidInput,
            };
            return (record, StepTiming::default());
        }
        let placement = &self.placement;
        let anchored = apply_planar_correction(
            &placement.anchored_from_odom,
            &placement.convention.to_planar(pose),
        );
        let step = self.corrector.push(anchored.planar_position());
        let corrected = match step.status {
            Status::InvalidInput => *pose,
            _ => {
                let published = match &mut self.smoother {
                    Some(smoother) if self.corrector.stood_still() => {
                        smoother.hold(step.map_from_anchored)
                    }
                    Some(smoother) => {
                        smoother.next(step.map_from_anchored, anchored.planar_position())
                    }
                    None => step.map_from_anchored,
                };
                let in_map = apply_planar_correction(&published, &anchored);
                placement
                    .convention
                    .from_planar(&apply_planar_correction(&self.odom_from_anchored, &in_map))
            }
        };
        let record = CorrectedPose {
            pose: corrected,
            map_from_odom: step.map_from_anchored * placement.anchored_from_odom,
            covariance: step.covariance,
            status: step.status,
        };
        (record, step.timing)
    }
}

/// Corrects a whole recorded trajectory pose by pose, exactly as the online corrector sees it:
/// the output is in the input's own frame and convention.
pub fn correct_trajectory(
    map: Arc<LaneMap>,
    params: Params,
    mode: MatchMode,
    placement: Placement,
    poses: &[Pose3],
) -> Vec<CorrectedPose> {
    let mut corrector = SourceCorrector::new(map, params, mode, placement);
    poses.iter().map(|pose| corrector.correct(pose).0).collect()
}

/// Counts over a corrected run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counts {
    /// Steps where matching ran (the reference figures' "attempts").
    pub attempts: usize,
    /// Accepted corrections.
    pub accepted: usize,
    /// Window resets.
    pub resets: usize,
}

/// The counts of a corrected run.
pub fn counts(run: &[CorrectedPose]) -> Counts {
    let mut c = Counts::default();
    for pose in run {
        c.attempts += pose.status.attempted() as usize;
        c.accepted += matches!(pose.status, Status::Accepted { .. }) as usize;
        c.resets += matches!(pose.status, Status::Reset { .. }) as usize;
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lane_map::Lane;
    use crate::params::Preset;

    #[test]
    fn any_non_finite_number_is_invalid_input_and_changes_nothing() {
        let lane = Lane::new(1, (0..100).map(|i| [i as f64 * 3.0, 0.0]).collect());
        let map = Arc::new(LaneMap::new(&[lane]).unwrap());
        let placement = Placement {
            convention: AxisConvention::Flu,
            anchored_from_odom: Se2::IDENTITY,
            smoothing: None,
        };
        let mut c = SourceCorrector::new(map, Preset::KissIcp.params(), MatchMode::Fast, placement);
        c.correct(&Pose3::planar(0.0, 0.5, 0.0, 0.0));
        // Height and roll are not part of the planar position, yet must be plausible too.
        for (row, col, value) in [
            (2, 3, f64::INFINITY),
            (2, 1, f64::NAN),
            (0, 3, f64::NAN),
            (2, 3, 1e8),
            (2, 2, 0.0),
        ] {
            let mut v = Pose3::planar(1.0, 0.5, 0.0, 0.0).to_row_major();
            v[row * 4 + col] = value;
            let (record, _) = c.correct(&Pose3::from_row_major(&v));
            assert_eq!(record.status, Status::InvalidInput);
            assert_eq!(
                record.pose.to_row_major()[row * 4 + col].to_bits(),
                value.to_bits()
            );
        }
        let (next, _) = c.correct(&Pose3::planar(1.0, 0.5, 0.0, 0.0));
        assert_eq!(next.status, Status::WarmingUp { window_len: 2 });
    }
}
