//! One source's corrector with its placement on the map: takes poses in the source's own frame
//! and axis convention and returns them corrected in the same. The daemon runs one per session;
//! [`correct_trajectory`] runs one over a whole recorded file, so both give the same answers.
//!
//! Frames: `odom` is the source's planar odometry frame (after its axis convention is turned
//! into `flu`); `anchored` is the map plane as the anchor places the odometry, before any
//! correction; `scaled` is `anchored` with the odometry's steps multiplied by the estimate of its
//! scale ([`crate::scale`]; the same as `anchored` where the scale is not estimated), the plane
//! the corrector works in; `map` is the corrected map plane. `map_from_odom = map_from_scaled *
//! scaled_from_anchored * anchored_from_odom`, where `scaled_from_anchored` is a translation
//! that changes with every step while the scale estimate is not 1.

use std::sync::Arc;
use std::time::Instant;

use crate::confidence::{widened_by, Covariance};
use crate::continuity::{Continued, Continuity};
use crate::corrector::{Corrector, CorrectorState, MatchMode, Status, StepTiming};
use crate::lane_map::LaneMap;
use crate::params::Params;
use crate::pose::{apply_planar_correction, AxisConvention, Pose3};
use crate::scale::ScaledOdometry;
use crate::se2::Se2;
use crate::smoothing::{Smoother, Smoothing};
use crate::stall::{StallState, StallWatch, Widening};

/// The per-pose record of a correction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CorrectedPose {
    /// The corrected pose, in the input's frame and axis convention (smoothed when the source
    /// asks for smooth output; the input unchanged for invalid input). After a jump of the
    /// odometry, in the frame the source had before it: the output continues where it was.
    pub pose: Pose3,
    /// The exact correction in force after this pose, never smoothed: maps planar odometry
    /// coordinates (the frame the source publishes in now) onto the corrected map plane (the
    /// anchor's placement composed with the accumulated correction and, after a jump of the
    /// odometry, with what carries its new frame onto its old one).
    pub map_from_odom: Se2,
    /// The covariance of the exact corrected pose's error (map plane; x, y in metres, yaw in
    /// radians; see [`crate::confidence`]). NaN for invalid input, which has no corrected pose.
    pub covariance: Covariance,
    /// What the corrector did.
    pub status: Status,
    /// What the odometry's steps are multiplied by after this pose: the estimate of its scale
    /// (a ratio; 1 where the scale is not estimated, [`Params::scale_sigma`]). NaN for invalid
    /// input, as on the wire.
    pub odometry_scale: f64,
    /// The standard deviation of `odometry_scale` (a ratio; 0 where the scale is not estimated:
    /// it is then taken as exact). NaN for invalid input.
    pub odometry_scale_sd: f64,
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
    /// The odometry's own recent motion and its jumps so far.
    pub continuity: Continuity,
    /// The odometry's steps as the scale estimate multiplied them so far.
    pub scaled: ScaledOdometry,
    /// The watch for stalls of the odometry, where the source has one
    /// ([`Params::watch_stalls`]); `None` in a state saved before it, which then
    /// starts afresh.
    pub stall: Option<StallState>,
}

/// A corrector for one source: converts, places, corrects and converts back.
pub struct SourceCorrector {
    corrector: Corrector,
    placement: Placement,
    odom_from_anchored: Se2,
    anchor_yaw: f64,
    smoother: Option<Smoother>,
    continuity: Continuity,
    scaled: ScaledOdometry,
    /// Where [`Params::watch_stalls`]: the watch for stalls of the odometry.
    stall: Option<StallWatch>,
    /// Whether the last pose taken was a step taken for poses missing ([`Continued::OverGap`]).
    took_poses_missing: bool,
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
            continuity: Continuity::default(),
            scaled: ScaledOdometry::default(),
            stall: params
                .watch_stalls
                .then(|| StallWatch::new(params.odometry_rate_hz)),
            placement,
            took_poses_missing: false,
        }
    }

    /// The rotation of the source's anchor (radians): its planar odometry frame turned into the
    /// map plane before any correction.
    pub fn anchor_yaw(&self) -> f64 {
        self.anchor_yaw
    }

    /// Whether the last pose [`SourceCorrector::correct_at`] took was a step it took for poses
    /// missing ([`Continued::OverGap`]: longer than [`Params::max_speed_mps`] allows in one
    /// period, driving on as the step before, its stamps no clock); such a pose may as well be a
    /// glitch straight ahead, and its covariance covers that.
    pub fn took_poses_missing(&self) -> bool {
        self.took_poses_missing
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
        let planar = self.placement.convention.to_planar(pose);
        let in_continued = self.continuity.carry(&planar).planar_position();
        let in_anchored = self.placement.anchored_from_odom.apply(in_continued);
        let in_scaled = self
            .scaled
            .predict(in_anchored, self.corrector.odometry_scale());
        self.corrector.map_from_anchored().apply(in_scaled)
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
            continuity: self.continuity,
            scaled: self.scaled,
            stall: self.stall.as_ref().map(StallWatch::state),
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
            continuity: state.continuity,
            scaled: state.scaled,
            stall: params.watch_stalls.then(|| match state.stall {
                Some(saved) => StallWatch::restore(params.odometry_rate_hz, saved),
                None => StallWatch::new(params.odometry_rate_hz),
            }),
            placement,
            took_poses_missing: false,
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

    /// Corrects the next pose (`world_from_body` in the source's convention) of a source
    /// without stamps; see [`SourceCorrector::correct_at`].
    pub fn correct(&mut self, pose: &Pose3) -> (CorrectedPose, StepTiming) {
        self.correct_at(pose, f64::NAN)
    }

    /// Corrects the next pose (`world_from_body` in the source's convention), stamped `stamp_s`
    /// (seconds; NaN without a stamp, when one period of [`Params::odometry_rate_hz`] is assumed
    /// between poses); returns the step's timing too. A pose that is no pose
    /// ([`Pose3::problem`]: a non-finite number, an absurd coordinate, a rotation that is not
    /// one) is answered as invalid input and changes nothing. A pose the vehicle cannot have
    /// driven to is a jump of the odometry ([`crate::continuity`]): it is answered with the
    /// correction in force where the last motion leads, and the poses after it continue from
    /// there. Where the source watches stalls ([`Params::watch_stalls`]), an odometry whose speed
    /// falls faster than a car brakes widens the covariance by the road it may have missed and
    /// the turns it may have made there, and the window restarts ([`crate::stall`]).
    ///
    /// The timing's `total` is the whole of this call: besides the corrector's step, the
    /// conversion from and to the source's convention, the continuity and stall watches, the
    /// scale and the smoothing (docs/performance.md, "The source corrector's share", measures
    /// their share).
    pub fn correct_at(&mut self, pose: &Pose3, stamp_s: f64) -> (CorrectedPose, StepTiming) {
        let start = Instant::now();
        let (record, mut timing) = self.correct_untimed(pose, stamp_s);
        timing.total = start.elapsed();
        (record, timing)
    }

    /// [`SourceCorrector::correct_at`], the timing's `total` the corrector's step alone (zero
    /// where none ran: an invalid pose, a jump).
    fn correct_untimed(&mut self, pose: &Pose3, stamp_s: f64) -> (CorrectedPose, StepTiming) {
        if pose.problem().is_some() {
            self.took_poses_missing = false;
            let record = CorrectedPose {
                pose: *pose,
                map_from_odom: self.map_from_odom(),
                covariance: [[f64::NAN; 3]; 3],
                status: Status::InvalidInput,
                odometry_scale: f64::NAN,
                odometry_scale_sd: f64::NAN,
            };
            return (record, StepTiming::default());
        }
        let placement = &self.placement;
        let planar = placement.convention.to_planar(pose);
        let continued = self
            .continuity
            .observe(planar.to_se2(), stamp_s, self.corrector.params());
        self.took_poses_missing = matches!(continued, Continued::OverGap { .. });
        let mut anchored = apply_planar_correction(
            &placement.anchored_from_odom,
            &self.continuity.carry(&planar),
        );
        // From here on the pose is in frame `scaled`, the corrector's (the same as `anchored`
        // where the scale is not estimated).
        if self.corrector.estimates_scale() {
            self.scaled
                .place(anchored.planar_position(), self.corrector.odometry_scale());
            anchored = apply_planar_correction(&self.scaled.scaled_from_anchored(), &anchored);
        }
        if let Some(watch) = &mut self.stall {
            let corrector = &mut self.corrector;
            let position = anchored.planar_position();
            watch.observe(position, anchored.planar_heading(), stamp_s, |widening| {
                // The pose is in frame `scaled` here, the corrector's own: its correction turns
                // the direction into the map plane.
                corrector.drive_unseen(&Widening {
                    direction: corrector.map_from_anchored().rotate(widening.direction),
                    ..widening
                });
                if widening.began {
                    corrector.restart_window();
                }
            });
        }
        let (status, covariance, timing, published) = if continued == Continued::Jumped {
            let held = self.corrector.map_from_anchored();
            let published = match &mut self.smoother {
                Some(smoother) => smoother.hold(held),
                None => held,
            };
            let window_len = self.corrector.window().len();
            let status = Status::OdometryJump { window_len };
            let covariance = self.corrector.covariance();
            (status, covariance, StepTiming::default(), published)
        } else {
            let step = self.corrector.push(anchored.planar_position());
            let published = match &mut self.smoother {
                Some(smoother) if self.corrector.stood_still() => {
                    smoother.hold(step.map_from_anchored)
                }
                Some(smoother) => smoother.next(step.map_from_anchored, anchored.planar_position()),
                None => step.map_from_anchored,
            };
            // A step taken for poses missing may be a glitch straight ahead: the vehicle is then
            // where the drive leads, as far back as the pose lies beyond it.
            let covariance = match continued {
                Continued::OverGap { beyond } => {
                    let in_anchored = self.placement.anchored_from_odom.rotate(beyond);
                    let in_map = step.map_from_anchored.rotate(in_anchored);
                    widened_by(&step.covariance, in_map)
                }
                Continued::Moved | Continued::Jumped => step.covariance,
            };
            (step.status, covariance, step.timing, published)
        };
        let corrected = match status {
            Status::InvalidInput => *pose,
            _ => {
                let in_map = apply_planar_correction(&published, &anchored);
                self.placement
                    .convention
                    .from_planar(&apply_planar_correction(&self.odom_from_anchored, &in_map))
            }
        };
        let record = CorrectedPose {
            pose: corrected,
            map_from_odom: self.map_from_odom(),
            covariance,
            status,
            odometry_scale: self.corrector.odometry_scale(),
            odometry_scale_sd: self.corrector.odometry_scale_sd(),
        };
        (record, timing)
    }

    /// The exact correction in force: planar odometry coordinates (the frame the source
    /// publishes in now) onto the corrected map plane.
    fn map_from_odom(&self) -> Se2 {
        self.corrector.map_from_anchored()
            * self.scaled.scaled_from_anchored()
            * self.placement.anchored_from_odom
            * self.continuity.continued_from_odom
    }
}

/// Corrects a whole recorded trajectory pose by pose, exactly as the online corrector sees it:
/// the output is in the input's own frame and convention. The poses come at the rate the
/// parameters are set for ([`Params::odometry_rate_hz`]); see [`correct_stamped_trajectory`].
pub fn correct_trajectory(
    map: Arc<LaneMap>,
    params: Params,
    mode: MatchMode,
    placement: Placement,
    poses: &[Pose3],
) -> Vec<CorrectedPose> {
    correct_stamped_trajectory(map, params, mode, placement, poses, None)
}

/// [`correct_trajectory`] with each pose's stamp (seconds; `stamps_s[i]` for `poses[i]`, `None`
/// for a trajectory without stamps): an odometry's speed, which tells its jumps from its motion,
/// is judged by them ([`SourceCorrector::correct_at`]).
pub fn correct_stamped_trajectory(
    map: Arc<LaneMap>,
    params: Params,
    mode: MatchMode,
    placement: Placement,
    poses: &[Pose3],
    stamps_s: Option<&[f64]>,
) -> Vec<CorrectedPose> {
    let mut corrector = SourceCorrector::new(map, params, mode, placement);
    poses
        .iter()
        .enumerate()
        .map(|(i, pose)| corrector.correct_at(pose, stamp_at(stamps_s, i)).0)
        .collect()
}

/// The stamp of pose `i` (seconds), NaN when there are no stamps.
pub fn stamp_at(stamps_s: Option<&[f64]>, i: usize) -> f64 {
    stamps_s.and_then(|s| s.get(i)).copied().unwrap_or(f64::NAN)
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

impl Counts {
    /// Counts one more pose, answered with `status` (each count stops at `usize::MAX`).
    pub fn add(&mut self, status: &Status) {
        let count = |n: &mut usize, yes: bool| *n = n.saturating_add(usize::from(yes));
        count(&mut self.attempts, status.attempted());
        count(
            &mut self.accepted,
            matches!(status, Status::Accepted { .. }),
        );
        count(&mut self.resets, matches!(status, Status::Reset { .. }));
    }
}

/// The counts of a corrected run.
pub fn counts(run: &[CorrectedPose]) -> Counts {
    let mut c = Counts::default();
    run.iter().for_each(|pose| c.add(&pose.status));
    c
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lane_map::Lane;
    use crate::params::Preset;
    use crate::smoothing::Smoothing;

    /// An eastbound lane along the x axis from the origin, a point every 3 m.
    fn eastbound(points: usize) -> Arc<LaneMap> {
        let lane = Lane::new(1, (0..points).map(|i| [i as f64 * 3.0, 0.0]).collect());
        Arc::new(LaneMap::new(&[lane]).unwrap())
    }

    /// Poses in `flu` axes, their odometry frame the map's.
    fn on_the_map(smoothing: Option<Smoothing>) -> Placement {
        Placement {
            convention: AxisConvention::Flu,
            anchored_from_odom: Se2::IDENTITY,
            smoothing,
        }
    }

    #[test]
    fn any_non_finite_number_is_invalid_input_and_changes_nothing() {
        let map = eastbound(100);
        let placement = on_the_map(None);
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
            // No corrected pose, so no covariance or scale of one (as the daemon answers).
            assert!(record.covariance.iter().flatten().all(|v| v.is_nan()));
            assert!(record.odometry_scale.is_nan() && record.odometry_scale_sd.is_nan());
            assert_eq!(
                record.pose.to_row_major()[row * 4 + col].to_bits(),
                value.to_bits()
            );
        }
        let (next, _) = c.correct(&Pose3::planar(1.0, 0.5, 0.0, 0.0));
        assert_eq!(next.status, Status::WarmingUp { window_len: 2 });
    }

    #[test]
    fn a_jump_of_the_odometry_is_flagged_and_the_drive_goes_on_where_it_was() {
        // An eastbound lane; the odometry drives along it at 15 m/s, 0.5 m to its left, and
        // restarts at its origin at pose 300.
        let map = eastbound(400);
        let placement = on_the_map(Some(Smoothing::default()));
        let params = Preset::KissIcp.robust_params();
        let drive: Vec<Pose3> = (0..600)
            .map(|i| Pose3::planar(1.5 * i as f64, 0.5, 0.0, 0.0))
            .collect();
        let restarted: Vec<Pose3> = drive
            .iter()
            .enumerate()
            .map(|(i, p)| match i {
                0..300 => *p,
                _ => Pose3::planar(1.5 * (i - 300) as f64, 0.0, 0.0, 0.0),
            })
            .collect();
        let unbroken = correct_trajectory(map.clone(), params, MatchMode::Fast, placement, &drive);
        let run = correct_trajectory(map.clone(), params, MatchMode::Fast, placement, &restarted);
        for (i, (got, want)) in run.iter().zip(&unbroken).enumerate() {
            let (g, w) = (got.pose.planar_position(), want.pose.planar_position());
            assert!(
                (g[0] - w[0]).abs() < 1e-6 && (g[1] - w[1]).abs() < 1e-6,
                "pose {i}"
            );
            if i == 300 {
                let window_len = unbroken[299].status.window_len();
                assert_eq!(got.status, Status::OdometryJump { window_len });
                // The correction in force maps the odometry's new frame: its origin is where
                // the vehicle was.
                let [x, _] = got.map_from_odom.apply([0.0, 0.0]);
                assert!((x - 450.0).abs() < 1e-6, "{x}");
            } else if i < 300 {
                assert_eq!(got.status, want.status, "pose {i}");
            } else {
                // The jumped pose did not enter the window: one pose fewer in it.
                assert_eq!(got.status.name(), want.status.name(), "pose {i}");
                assert!(
                    want.status.window_len() - got.status.window_len() <= 1,
                    "pose {i}"
                );
            }
        }
        // Without the check the restart is taken for road: the output goes back to the start.
        let mut off = params;
        off.max_speed_mps = f64::INFINITY;
        let taken = correct_trajectory(map.clone(), off, MatchMode::Fast, placement, &restarted);
        assert!(taken[400].pose.planar_position()[0] < 200.0);
        // A corrector restored after the jump goes on as the one saved.
        let mut first = SourceCorrector::new(map.clone(), params, MatchMode::Fast, placement);
        for pose in &restarted[..350] {
            first.correct(pose);
        }
        let mut second =
            SourceCorrector::restore(map, params, MatchMode::Fast, placement, first.state());
        for pose in &restarted[350..] {
            assert_eq!(first.correct(pose).0, second.correct(pose).0);
        }
    }

    #[test]
    fn a_step_over_poses_missing_is_told_and_published_as_uncertain_as_a_glitch() {
        // An eastbound lane, driven at 15 m/s 0.5 m to its left; poses 300 to 329 are missing.
        let map = eastbound(400);
        let placement = on_the_map(None);
        let params = Preset::KissIcp.robust_params();
        let kept: Vec<usize> = (0..300).chain(330..400).collect();
        for stamped in [false, true] {
            let mut c = SourceCorrector::new(map.clone(), params, MatchMode::Fast, placement);
            for (k, &i) in kept.iter().enumerate() {
                let stamp_s = if stamped { i as f64 / 10.0 } else { f64::NAN };
                let (record, _) =
                    c.correct_at(&Pose3::planar(1.5 * i as f64, 0.5, 0.0, 0.0), stamp_s);
                let over_gap = !stamped && i == 330;
                assert_eq!(c.took_poses_missing(), over_gap, "pose {k}");
                let xx = record.covariance[0][0];
                if over_gap {
                    // 45 m beyond where one step leads: that far back if it was a glitch.
                    assert!(xx > 45.0 * 45.0 && xx < 46.0 * 46.0, "{xx}");
                } else {
                    assert!(xx < 25.0, "pose {k}: {xx}");
                }
            }
        }
    }

    /// A straight eastbound road 3 km long, driven at 20 m/s by an odometry that stalls for
    /// 3 s after 300 poses (0.2 m/s) and then goes on at 20 m/s: the poses in the odometry's
    /// frame, on the lane.
    fn stalled_drive() -> (Arc<LaneMap>, Vec<Pose3>) {
        let map = eastbound(1000);
        let mut x = 0.0;
        let poses = (0..600)
            .map(|i| {
                x += if (300..330).contains(&i) { 0.02 } else { 2.0 };
                Pose3::planar(x, 0.3, 0.0, 0.0)
            })
            .collect();
        (map, poses)
    }

    #[test]
    fn a_stall_restarts_the_window_and_widens_the_covariance_along_the_road() {
        let (map, poses) = stalled_drive();
        let placement = Placement {
            convention: AxisConvention::Flu,
            anchored_from_odom: Se2::new(0.0, 0.0, 0.0),
            smoothing: None,
        };
        let params = crate::params::Method::Robust.params(Preset::KissIcp);
        assert!(params.watch_stalls);
        let unwatched = Params {
            watch_stalls: false,
            ..params
        };
        let run = |params: Params| {
            let mut c = SourceCorrector::new(map.clone(), params, MatchMode::Fast, placement);
            poses.iter().map(|p| c.correct(p).0).collect::<Vec<_>>()
        };
        let (watched, before) = (run(params), run(unwatched));
        let told = watched
            .iter()
            .zip(&before)
            .position(|(a, b)| a != b)
            .expect("the stall changes the answers");
        assert!((300..312).contains(&told), "told at pose {told}");
        // The window restarted from the last pose that entered it (this one stands still).
        assert_eq!(watched[told].status.window_len(), 1);
        assert!(before[told].status.window_len() > 100);
        // 30 poses missed 1.98 m each along the road (x); across it (y) nothing changed.
        let missed_m = 30.0 * 1.98;
        for i in [340, 450, 599] {
            let (now, then) = (&watched[i].covariance, &before[i].covariance);
            let added = now[0][0] - then[0][0];
            assert!(
                (added.sqrt() - missed_m).abs() < 0.05 * missed_m,
                "pose {i}: {} m along the road",
                added.sqrt()
            );
        }
        // Across the road the lanes take it back to what it was once the window has warmed
        // up again after its restart.
        let (now, then) = (&watched[599].covariance, &before[599].covariance);
        assert!(now[1][1] < 1.2 * then[1][1], "{now:?} against {then:?}");
        // The corrections stay on the lane.
        assert!(watched
            .iter()
            .all(|c| (c.pose.planar_position()[1] - 0.3).abs() < 1.0));
    }

    #[test]
    fn a_corrector_restored_in_a_stall_goes_on_as_the_one_it_was_saved_from() {
        let (map, poses) = stalled_drive();
        let placement = Placement {
            convention: AxisConvention::Flu,
            anchored_from_odom: Se2::new(0.3, 5.0, -2.0),
            smoothing: None,
        };
        let params = crate::params::Method::Robust.params(Preset::KissIcp);
        let mut whole = SourceCorrector::new(map.clone(), params, MatchMode::Fast, placement);
        let expected: Vec<CorrectedPose> = poses.iter().map(|p| whole.correct(p).0).collect();
        for cut in [302, 306, 320, 335] {
            let mut first = SourceCorrector::new(map.clone(), params, MatchMode::Fast, placement);
            for p in &poses[..cut] {
                first.correct(p);
            }
            let state = first.state();
            assert!(state.stall.is_some());
            let mut restored =
                SourceCorrector::restore(map.clone(), params, MatchMode::Fast, placement, state);
            for (i, p) in poses.iter().enumerate().skip(cut) {
                assert_eq!(restored.correct(p).0, expected[i], "cut {cut}, pose {i}");
            }
        }
    }

    /// A block of lanes 300 m by 201 m, driven counter-clockwise from its south-west corner,
    /// a point every 3 m.
    fn block_map() -> Arc<LaneMap> {
        let side = |from: [f64; 2], to: [f64; 2], points: usize| -> Vec<[f64; 2]> {
            (0..=points)
                .map(|i| {
                    let f = i as f64 / points as f64;
                    [
                        from[0] + f * (to[0] - from[0]),
                        from[1] + f * (to[1] - from[1]),
                    ]
                })
                .collect()
        };
        let corners = [[0.0, 0.0], [300.0, 0.0], [300.0, 201.0], [0.0, 201.0]];
        let lanes: Vec<Lane> = (0..4)
            .map(|k| {
                let (from, to) = (corners[k], corners[(k + 1) % 4]);
                let points = (crate::se2::distance(from, to) / 3.0) as usize;
                Lane::new(k as u64 + 1, side(from, to, points))
            })
            .collect();
        Arc::new(LaneMap::new(&lanes).unwrap())
    }

    /// `laps` of the block at 1 m a pose (10 m/s at the presets' rate): true planar poses.
    fn block_drive(laps: usize) -> Vec<Pose3> {
        let corners = [[0.0, 0.0], [300.0, 0.0], [300.0, 201.0], [0.0, 201.0]];
        let mut poses = Vec::new();
        for _ in 0..laps {
            for k in 0..4 {
                let (from, to) = (corners[k], corners[(k + 1) % 4]);
                let length = crate::se2::distance(from, to);
                let yaw = (to[1] - from[1]).atan2(to[0] - from[0]);
                for i in 0..length as usize {
                    let f = i as f64 / length;
                    poses.push(Pose3::planar(
                        from[0] + f * (to[0] - from[0]),
                        from[1] + f * (to[1] - from[1]),
                        yaw,
                        0.0,
                    ));
                }
            }
        }
        poses
    }

    #[test]
    fn an_odometry_three_percent_long_has_its_scale_estimated_and_taken_out() {
        let truth = block_drive(4);
        let odometry: Vec<Pose3> = truth
            .iter()
            .map(|p| {
                let [x, y] = p.planar_position();
                Pose3::planar(1.03 * x, 1.03 * y, p.planar_heading(), 0.0)
            })
            .collect();
        let placement = on_the_map(None);
        let mut params = Preset::KissIcp.robust_params();
        params.scale_sigma = 0.05;
        let mut unscaled = params;
        unscaled.scale_sigma = 0.0;
        let last_lap_error = |run: &[CorrectedPose]| {
            let lap = run.len() - run.len() / 4;
            run[lap..]
                .iter()
                .zip(&truth[lap..])
                .map(|(c, t)| crate::se2::distance(c.pose.planar_position(), t.planar_position()))
                .sum::<f64>()
                / (run.len() - lap) as f64
        };
        let run = correct_trajectory(block_map(), params, MatchMode::Fast, placement, &odometry);
        let without =
            correct_trajectory(block_map(), unscaled, MatchMode::Fast, placement, &odometry);
        let (with_m, without_m) = (last_lap_error(&run), last_lap_error(&without));
        let factor = run[run.len() - 1].odometry_scale;
        println!("last lap: {with_m:.3} m with the scale estimated ({factor:.5}), {without_m:.3} m without");
        // 1 / 1.03 = 0.971; the lanes' band leaves what fits within it (0.977 here).
        assert!((0.965..0.98).contains(&factor), "{factor}");
        assert!(without[without.len() - 1].odometry_scale == 1.0);
        assert!(with_m < 0.5 * without_m, "{with_m} vs {without_m}");
        // The published map_from_odom holds exactly for the pose it came with.
        for c in &run {
            let [x, y] = c.map_from_odom.apply(odometry[0].planar_position());
            assert!(x.is_finite() && y.is_finite());
        }
        for (i, c) in run.iter().enumerate().step_by(97) {
            let mapped = c.map_from_odom.apply(odometry[i].planar_position());
            let [x, y] = c.pose.planar_position();
            assert!(
                (mapped[0] - x).abs() < 1e-9 && (mapped[1] - y).abs() < 1e-9,
                "pose {i}"
            );
        }
        // A corrector restored mid-drive goes on as the one saved, bit for bit.
        for cut in [700, 1900, 3100] {
            let mut first = SourceCorrector::new(block_map(), params, MatchMode::Fast, placement);
            for pose in &odometry[..cut] {
                first.correct(pose);
            }
            let mut restored = SourceCorrector::restore(
                block_map(),
                params,
                MatchMode::Fast,
                placement,
                first.state(),
            );
            for (i, pose) in odometry.iter().enumerate().skip(cut) {
                assert_eq!(restored.correct(pose).0, run[i], "cut at {cut}, pose {i}");
            }
        }
    }
}
