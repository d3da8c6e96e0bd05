//! Jumps of the odometry: a pose no drive can reach from the last one.
//!
//! An odometry that restarts (back at its origin, its heading zero) or relocalises (a SLAM
//! system that closes a loop) keeps publishing, but in another frame. Fed on, the corrector
//! would take the jump for road: the corrected poses would land where the odometry's new frame
//! puts them (on KITTI 00, where the drive began) with the correction and the confidence of the
//! old frame. [`Continuity`] tells a jump from motion by speed ([`Params::max_speed_mps`]) over
//! the time between the poses (their stamps, at least one period of
//! [`Params::odometry_rate_hz`]), and by what a car cannot do at any rate: triple its speed
//! between two poses ([`MAX_STEP_GROWTH`]; the first step, with none before it, is not judged).
//! It continues the odometry from where the vehicle was: the jumped pose is placed one step of
//! the last motion on from the last pose (position and heading), and every later pose is
//! carried over from the new frame by the same transform.
//!
//! A glitch (one pose published off the drive, the next on it again) is told by the pose after
//! it: when that pose would be a jump too, but continues the drive from the pose before the
//! glitch in the frame the odometry had then ([`BeforeGlitch`]), the odometry goes on in that
//! frame as if the glitch had not been.
//!
//! Only positions are judged. A heading can turn in one step in odometry that is not wrong (a
//! source that updates its heading less often than its position; the synthetic town's corners,
//! 90 degrees in one pose), and a turn taken for a jump would be lost for good; a jump of the
//! heading alone (an odometry restarted within a few metres of its origin) is left to the
//! alignment, which corrects heading.
//!
//! Without stamps (or with stamps that advance by less than half a period: an index, a unit too
//! small) the time between two poses is not known, and poses can be missing (an odometry that
//! lost track for a second, a file written only while it tracked): the step over the gap is then
//! longer than the speed limit allows in one period. Such a step is motion when it continues the
//! last step as a car drives on, at that step's curvature, whatever the speed
//! ([`MAX_GAP_CHORD_DEVIATION`], [`MAX_GAP_TURN_CHANGE`]): the chord of an arc leaves at half its
//! turn; it may also be a glitch straight ahead, which only the pose after it shows
//! ([`Continued::OverGap`]). An odometry that restarts or relocalises lands
//! somewhere its last motion does not lead to, and is a jump. Stamps that advance by half a
//! period or more are a clock: they time the step (poses missing show as a longer interval), and
//! the speed alone judges it, so a glitch straight ahead is a jump too.
//!
//! Frames: `odom` is the source's planar odometry frame as it publishes it now; `continued` is
//! the frame of the session's first pose, which the corrector sees throughout.
//! `continued_from_odom` is the identity until the first jump.

use crate::params::Params;
use crate::pose::{apply_planar_correction, Pose3};
use crate::se2::{wrap_angle, Se2};

/// How many times longer than the step before a step must be to be a jump. A car
/// does not triple its speed between two poses: from the fastest step the speed limit allows at
/// the presets' rate (7 m at 10 Hz), the step before would have been at least 2.3 m (23 m/s).
pub const MAX_STEP_GROWTH: f64 = 3.0;

/// How far (radians) the chord of a step over missing poses may point from where the last
/// step's arc, continued, leads: 10 degrees. Entering or leaving a bend during the gap moves the
/// chord by a sixth of the gap's turn (a clothoid's chord leaves at a third or two thirds of its
/// turn, an arc's at half), so a bend of up to 60 degrees taken unseen is motion; an odometry
/// that restarts passes only when its origin happens to lie this close to straight ahead.
pub const MAX_GAP_CHORD_DEVIATION: f64 = 10.0 * std::f64::consts::PI / 180.0;

/// How much more (radians) a step over missing poses may turn than the last step's curvature
/// gives over its length: 45 degrees, a bend begun or ended during the gap.
pub const MAX_GAP_TURN_CHANGE: f64 = 45.0 * std::f64::consts::PI / 180.0;

/// The length of a planar step (metres).
fn length(step: &Se2) -> f64 {
    let [dx, dy] = step.translation();
    dx.hypot(dy)
}

/// Whether `motion` (a step too long for one period, `before_from_after`, planar) continues
/// `last_motion` (the step before it) as a car driving on through poses that are missing: its
/// turn within [`MAX_GAP_TURN_CHANGE`] of the last step's curvature over its length, its chord
/// within [`MAX_GAP_CHORD_DEVIATION`] of the direction of travel turned by half that turn. A
/// last step shorter than `min_step_m` (a standing car) gives no direction to continue.
fn continues_the_drive(last_motion: &Se2, motion: &Se2, min_step_m: f64) -> bool {
    let last_length = length(last_motion);
    if !(last_length >= min_step_m && last_length > 0.0) {
        return false;
    }
    let [lx, ly] = last_motion.translation();
    let last_turn = last_motion.yaw();
    // The last step's chord leaves at half its turn: its arc ends heading half a turn further,
    // which in the frame of the last pose (turned by the whole turn) is half a turn back.
    let travel = ly.atan2(lx) - last_turn / 2.0;
    let turn = motion.yaw();
    let expected_turn = last_turn / last_length * length(motion);
    let [x, y] = motion.translation();
    wrap_angle(turn - expected_turn).abs() <= MAX_GAP_TURN_CHANGE
        && wrap_angle(y.atan2(x) - travel - turn / 2.0).abs() <= MAX_GAP_CHORD_DEVIATION
}

/// The motion `h` that, taken twice, is `motion` (both `before_from_after`, planar): half the
/// turn, and the translation `t_h` with `t_h + R(turn / 2) t_h = t`, for every turn (the half
/// turn lies within (-pi/2, pi/2], where `I + R` is invertible).
fn half_of(motion: &Se2) -> Se2 {
    let half_turn = motion.yaw() / 2.0;
    let (sin, cos) = half_turn.sin_cos();
    let [x, y] = motion.translation();
    // (I + R)^-1 for R = [[cos, -sin], [sin, cos]]: [[1 + cos, sin], [-sin, 1 + cos]] over
    // (1 + cos)^2 + sin^2 = 2 (1 + cos), at least 2 for a half turn within (-pi/2, pi/2].
    let det = 2.0 * (1.0 + cos);
    Se2::new(
        half_turn,
        ((1.0 + cos) * x + sin * y) / det,
        (-sin * x + (1.0 + cos) * y) / det,
    )
}

/// What is known of the odometry's own motion, to tell a jump from a drive.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Continuity {
    /// Carries the odometry frame as the source publishes it now onto the `continued` frame.
    pub continued_from_odom: Se2,
    /// The last valid pose (`continued_from_body`, planar) and its stamp (seconds; NaN without
    /// one).
    pub last: Option<(Se2, f64)>,
    /// The motion of the last step (`before_from_after`, planar); `None` before the first.
    pub last_motion: Option<Se2>,
    /// The odometry as it was before its last pose, when that pose jumped or was taken for a
    /// step over missing poses: the pose after it may show that it was a glitch.
    pub before_glitch: Option<BeforeGlitch>,
}

impl Default for Continuity {
    fn default() -> Self {
        Continuity {
            continued_from_odom: Se2::IDENTITY,
            last: None,
            last_motion: None,
            before_glitch: None,
        }
    }
}

/// The odometry before a pose that may be a glitch (a single pose published off its drive: a
/// corrupt message, a failed registration the next one mends), to go on from if the pose after
/// it continues the drive from there.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BeforeGlitch {
    /// [`Continuity::continued_from_odom`] before the pose.
    pub continued_from_odom: Se2,
    /// [`Continuity::last`] before the pose: the last pose of the drive and its stamp.
    pub last: (Se2, f64),
    /// [`Continuity::last_motion`] before the pose.
    pub last_motion: Se2,
}

/// Whether a step of `moved_m` metres over `elapsed_s` seconds is more than a vehicle drives:
/// faster than [`Params::max_speed_mps`] and more than [`MAX_STEP_GROWTH`] times
/// `usual_step_m`, the length the drive's steps had before it.
fn beyond_a_drive(moved_m: f64, elapsed_s: f64, usual_step_m: f64, params: &Params) -> bool {
    moved_m > params.max_speed_mps * elapsed_s && moved_m > MAX_STEP_GROWTH * usual_step_m
}

/// How a pose continued the odometry.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Continued {
    /// A step the vehicle can drive.
    Moved,
    /// A jump: the pose was placed where the last motion leads.
    Jumped,
    /// A step past the limits taken for poses missing from an input without a clock: it drives
    /// on as the last step did. It may as well be a glitch that landed straight ahead, which
    /// only the pose after it can show.
    OverGap {
        /// How far the pose lies beyond where one step of the last motion leads from the last
        /// pose (metres, `continued` frame): where the vehicle is if the pose was a glitch.
        beyond: [f64; 2],
    },
}

impl Continuity {
    /// `odom_from_body` (a planar pose in the frame the source publishes in now) carried into
    /// the `continued` frame; unchanged, bit for bit, until the first jump.
    pub fn carry(&self, odom_from_body: &Pose3) -> Pose3 {
        if self.continued_from_odom == Se2::IDENTITY {
            *odom_from_body
        } else {
            apply_planar_correction(&self.continued_from_odom, odom_from_body)
        }
    }

    /// Takes the next valid pose (`odom_from_body`, planar) with its stamp (seconds; NaN without
    /// one); returns whether it jumped. After a jump, [`Continuity::continued_from_odom`] carries
    /// it (and the poses after it) to where the last motion leads from the last pose.
    pub fn observe(&mut self, odom_from_body: Se2, stamp_s: f64, params: &Params) -> Continued {
        let before_glitch = self.before_glitch.take();
        let continued = self.continued_from_odom * odom_from_body;
        let Some((last, last_stamp_s)) = self.last else {
            self.last = Some((continued, stamp_s));
            return Continued::Moved;
        };
        let motion = last.inverse() * continued;
        // The first step has no step before it to be judged against: a source slower than its
        // set rate that starts at speed would otherwise jump on it.
        let Some(last_motion) = self.last_motion else {
            self.last = Some((continued, stamp_s));
            self.last_motion = Some(motion);
            return Continued::Moved;
        };
        // The stamps can only lengthen the time between two poses beyond one period of the set
        // rate (an odometry that paused): stamps that are absent, repeated, reset or in a unit too
        // small would otherwise make every step a jump.
        let (since_last_s, period_s) = (stamp_s - last_stamp_s, 1.0 / params.odometry_rate_hz);
        let elapsed_s = since_last_s.max(period_s);
        let moved_m = length(&motion);
        // A step is a jump when the vehicle could not drive it in the time, and when it is
        // more than [`MAX_STEP_GROWTH`] times the step before: a source slower than its set
        // rate (poses far apart, all alike) is not one.
        if beyond_a_drive(moved_m, elapsed_s, length(&last_motion), params) {
            // The pose before may have been the glitch: read in the frame before it, this pose
            // may continue the drive from the pose before that, two steps on.
            if let Some(before) = before_glitch {
                let resumed = before.continued_from_odom * odom_from_body;
                let (before_last, before_stamp_s) = before.last;
                let elapsed_s = (stamp_s - before_stamp_s).max(2.0 * period_s);
                let usual_step_m = 2.0 * length(&before.last_motion);
                let two_steps = before_last.inverse() * resumed;
                if !beyond_a_drive(length(&two_steps), elapsed_s, usual_step_m, params) {
                    self.continued_from_odom = before.continued_from_odom;
                    self.last = Some((resumed, stamp_s));
                    // The step of one pose, for the next to be judged against and predicted
                    // with: glitches on every other pose would otherwise leave it as it was
                    // before the first.
                    self.last_motion = Some(half_of(&two_steps));
                    return Continued::Moved;
                }
            }
            self.before_glitch = Some(BeforeGlitch {
                continued_from_odom: self.continued_from_odom,
                last: (last, last_stamp_s),
                last_motion,
            });
            // Stamps that advance by half a period or more are a clock: they tell how long the
            // step took (poses missing show as a longer interval), and the speed has judged it.
            // Without one (no stamps, stamps repeated, reset, an index or in a unit too small)
            // the step may still span poses missing from the input.
            let timed = since_last_s >= 0.5 * period_s;
            if !timed && continues_the_drive(&last_motion, &motion, params.standstill_distance_m())
            {
                // The last motion stays the step of one pose, for the next step to be judged
                // against and a later jump to be predicted with.
                self.last = Some((continued, stamp_s));
                let ([x, y], [px, py]) =
                    (continued.translation(), (last * last_motion).translation());
                return Continued::OverGap {
                    beyond: [x - px, y - py],
                };
            }
            let predicted = last * last_motion;
            // Renormalised: the frame is composed from its own earlier value at every jump.
            self.continued_from_odom = (predicted * odom_from_body.inverse()).normalized();
            self.last = Some((predicted, stamp_s));
            return Continued::Jumped;
        }
        self.last = Some((continued, stamp_s));
        self.last_motion = Some(motion);
        Continued::Moved
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::params::Preset;

    fn close(a: Se2, b: Se2) -> bool {
        let [ax, ay] = a.translation();
        let [bx, by] = b.translation();
        (ax - bx).abs() < 1e-9
            && (ay - by).abs() < 1e-9
            && wrap_angle(a.yaw() - b.yaw()).abs() < 1e-12
    }

    #[test]
    fn a_restarted_odometry_continues_where_the_vehicle_was() {
        let params = Preset::KissIcp.robust_params();
        let mut c = Continuity::default();
        // 1.5 m a pose (15 m/s at 10 Hz), the heading turning gently.
        let drive = |i: usize| Se2::new(0.5 + 0.01 * i as f64, 100.0 + 1.5 * i as f64, 50.0);
        for i in 0..10 {
            assert_eq!(c.observe(drive(i), f64::NAN, &params), Continued::Moved);
        }
        assert!(close(c.continued_from_odom, Se2::IDENTITY));
        // The odometry restarts: its next pose is its origin.
        assert_eq!(
            c.observe(Se2::IDENTITY, f64::NAN, &params),
            Continued::Jumped
        );
        let (at_jump, _) = c.last.unwrap();
        let step = drive(8).inverse() * drive(9);
        assert!(close(at_jump, drive(9) * step), "{at_jump:?}");
        // It drives on in its new frame: carried on from there, step for step.
        let onwards = Se2::new(0.0, 1.5, 0.0);
        assert_eq!(c.observe(onwards, f64::NAN, &params), Continued::Moved);
        let (next, _) = c.last.unwrap();
        assert!(close(next, at_jump * onwards), "{next:?}");
    }

    #[test]
    fn speed_is_judged_by_the_stamps_and_a_turn_is_never_a_jump() {
        let params = Preset::KissIcp.robust_params();
        // After a step of 1 m, 20 m to the side in one period of 10 Hz is 200 m/s: a jump.
        let mut c = Continuity::default();
        c.observe(Se2::IDENTITY, 5.0, &params);
        c.observe(Se2::new(0.0, 1.0, 0.0), 5.1, &params);
        assert_eq!(
            c.observe(Se2::new(0.0, 1.0, 20.0), 5.2, &params),
            Continued::Jumped
        );
        // The same 20 m over a second the odometry paused (stamps 1 s apart) is 20 m/s: motion.
        let mut c = Continuity::default();
        c.observe(Se2::IDENTITY, 5.0, &params);
        c.observe(Se2::new(0.0, 1.0, 0.0), 5.1, &params);
        assert_eq!(
            c.observe(Se2::new(0.0, 1.0, 20.0), 6.1, &params),
            Continued::Moved
        );
        // A stamp that does not move forward, or moves less than one period of the set rate
        // (stamps in a unit too small), counts as one period.
        assert_eq!(
            c.observe(Se2::new(0.0, 81.0, 20.0), 6.1, &params),
            Continued::Jumped
        );
        assert_eq!(
            c.observe(Se2::new(0.0, 81.5, 20.0), 6.100_001, &params),
            Continued::Moved
        );
        assert_eq!(
            c.observe(Se2::new(0.0, 81.5, 40.0), 6.100_002, &params),
            Continued::Jumped
        );
        // A turn is never a jump, however sharp: a corner taken in one pose is not lost.
        let mut c = Continuity::default();
        c.observe(Se2::IDENTITY, f64::NAN, &params);
        c.observe(Se2::new(0.0, 1.0, 0.0), f64::NAN, &params);
        assert_eq!(
            c.observe(Se2::new(1.6, 2.0, 0.0), f64::NAN, &params),
            Continued::Moved
        );
    }

    #[test]
    fn a_step_that_drives_on_spans_missing_poses_unless_the_stamps_time_it() {
        let params = Preset::KissIcp.robust_params();
        let walk = |stamps: [f64; 3], last: Se2| {
            let mut c = Continuity::default();
            c.observe(Se2::new(0.3, 0.0, 0.0), stamps[0], &params);
            c.observe(Se2::new(0.3, 1.0, 0.0), stamps[1], &params);
            (c.observe(last, stamps[2], &params), c.continued_from_odom)
        };
        let over_gap = |got: Continued| match got {
            Continued::OverGap { beyond } => Some(beyond),
            _ => None,
        };
        // 1 m a pose along x (heading 0.3 rad: the direction of travel is the motion's, not the
        // body's), then 20 m on: poses missing, without stamps or with stamps that are no clock
        // (repeated, an index of 1 ns a pose, milliseconds sent as nanoseconds). The pose lies
        // 19 m beyond where one step leads.
        let on = Se2::new(0.3, 21.0, 0.0);
        for stamps in [
            [f64::NAN; 3],
            [7.0, 7.0, 7.0],
            [1e-9, 2e-9, 3e-9],
            [1e-7, 2e-7, 3e-7],
        ] {
            let (got, frame) = walk(stamps, on);
            let [x, y] = over_gap(got).unwrap_or_else(|| panic!("{stamps:?}: {got:?}"));
            assert!((x - 19.0).abs() < 1e-9 && y.abs() < 1e-9, "{x} {y}");
            assert_eq!(frame, Se2::IDENTITY);
        }
        // Bending 20 degrees on the way, as a road would (the chord at half the turn), is the
        // same.
        let bend = 20f64.to_radians();
        let (sin, cos) = (bend / 2.0).sin_cos();
        let bent = Se2::new(0.3 + bend, 1.0 + 20.0 * cos, 20.0 * sin);
        assert!(over_gap(walk([f64::NAN; 3], bent).0).is_some());
        // Stamps that advance as a clock time the step: 20 m in the period of the set rate, in
        // half of it, or over one pose missing (0.2 s) is a jump.
        for stamps in [[0.0, 0.1, 0.2], [0.0, 0.05, 0.1], [0.0, 0.1, 0.3]] {
            assert_eq!(walk(stamps, on).0, Continued::Jumped, "{stamps:?}");
        }
        // Off the direction of travel, or turned unlike the road, it is a jump.
        for off in [
            Se2::new(0.3, 21.0, 5.0),
            Se2::new(0.3, -19.0, 0.0),
            Se2::new(0.3 + 1.2, 21.0, 0.0),
        ] {
            assert_eq!(walk([f64::NAN; 3], off).0, Continued::Jumped, "{off:?}");
        }
    }

    #[test]
    fn a_source_slower_than_its_set_rate_does_not_jump_on_every_pose() {
        // 1 Hz poses without stamps read at the presets' 10 Hz: a car that starts at 20 m/s
        // (its first step, 20 m, has none before it to be judged against) is no jump; nor one
        // that sets off and accelerates to 25 m/s, turning at the end; a restart at the origin
        // afterwards is.
        let params = Preset::KissIcp.robust_params();
        let mut c = Continuity::default();
        c.observe(Se2::new(0.0, -500.0, 0.0), f64::NAN, &params);
        assert_eq!(
            c.observe(Se2::new(0.0, -480.0, 0.0), f64::NAN, &params),
            Continued::Moved
        );
        let mut c = Continuity::default();
        let (mut pose, mut speed, mut turn) = (Se2::new(0.3, 800.0, -200.0), 0.0, 0.0);
        for i in 0..20 {
            assert_eq!(
                c.observe(pose, f64::NAN, &params),
                Continued::Moved,
                "pose {i}"
            );
            speed = f64::min(speed + 3.0, 25.0);
            if i >= 15 {
                turn = 30f64.to_radians();
            }
            pose = pose * Se2::new(turn, speed, 0.0);
        }
        assert_eq!(
            c.observe(Se2::IDENTITY, f64::NAN, &params),
            Continued::Jumped
        );
    }

    #[test]
    fn an_odometry_that_keeps_changing_frame_keeps_a_rigid_one() {
        // Every tenth pose the odometry relocalises into a frame 1 km away and turned, and
        // goes on in it: each change is a jump. The frame is composed from its own earlier
        // value at each jump and the steps between from it; unrenormalised, the rounding of its
        // rotation entries multiplied at every jump (KITTI 00 with a glitch every tenth pose
        // had its corrected poses scaled by 1e39 within 80 jumps).
        let params = Preset::KissIcp.robust_params();
        let change = Se2::new(2.0, 1000.0, -700.0);
        let mut frame = Se2::IDENTITY;
        let mut c = Continuity::default();
        for i in 0..4000 {
            if i % 10 == 5 {
                frame = change * frame;
            }
            let drive = Se2::new(0.001 * i as f64, 1.2 * i as f64, 0.05 * i as f64);
            let got = c.observe(frame * drive, f64::NAN, &params);
            assert_eq!(got == Continued::Jumped, i % 10 == 5, "pose {i}");
            let (cos, sin) = c.continued_from_odom.rotation();
            assert!(
                (cos.hypot(sin) - 1.0).abs() < 1e-12,
                "pose {i}: {cos} {sin}"
            );
        }
    }

    #[test]
    fn half_a_motion_taken_twice_is_the_motion() {
        for motion in [
            Se2::new(0.0, 2.0, 0.0),
            Se2::new(0.3, 1.5, 0.2),
            Se2::new(-3.0, -4.0, 7.0),
            Se2::new(3.1, 0.5, -0.5),
        ] {
            let half = half_of(&motion);
            assert!(close(half * half, motion), "{motion:?}: {half:?}");
        }
    }

    #[test]
    fn a_glitch_of_one_pose_changes_nothing_after_it() {
        // One pose in ten is published off the drive (a corrupt message, a failed
        // registration), the next one on it again. Off to the side it is a jump, and so it is
        // straight ahead with stamps; straight ahead without stamps it is taken for poses
        // missing. Either way the pose after it continues the drive from the pose before it, in
        // the frame it had: nothing of the glitch stays. Before, the pose after a glitch jumped
        // too, back into the drive's frame moved by the prediction's error (centimetres a
        // glitch), and after a glitch ahead taken for missing poses the drive went on 500 m
        // ahead.
        let params = Preset::KissIcp.robust_params();
        let drive = |i: usize| Se2::new(0.001 * i as f64, 1.2 * i as f64, 0.05 * i as f64);
        for (off, stamped, every) in [
            (Se2::new(0.0, 0.0, 500.0), false, 10),
            (Se2::new(0.0, 0.0, 500.0), true, 10),
            (Se2::new(1.0, -300.0, -400.0), false, 10),
            (Se2::new(1.0, -300.0, -400.0), false, 2),
        ] {
            let mut c = Continuity::default();
            let (mut glitches, mut expected) = (0, 0);
            for i in 0..1000 {
                let glitch = i >= 10 && i % every == every / 2;
                expected += usize::from(glitch);
                let published = if glitch { off * drive(i) } else { drive(i) };
                let stamp = if stamped { i as f64 / 10.0 } else { f64::NAN };
                let got = c.observe(published, stamp, &params);
                if glitch {
                    glitches += usize::from(got == Continued::Jumped);
                    // Placed one step of the drive on, the step as the drive turned it (also
                    // when every other pose is a glitch: the step is taken from the two poses
                    // around the last).
                    let ([x, y], [dx, dy]) =
                        (c.last.unwrap().0.translation(), drive(i).translation());
                    assert!((x - dx).hypot(y - dy) < 0.01, "pose {i}: {x} {y}");
                    continue;
                }
                assert_eq!(got, Continued::Moved, "pose {i}");
                assert_eq!(c.continued_from_odom, Se2::IDENTITY, "pose {i}");
                assert!(close(c.last.unwrap().0, drive(i)), "pose {i}");
            }
            assert_eq!(glitches, expected, "{off:?} {stamped}");
        }
        // Straight ahead along the drive: without stamps it is taken for poses missing (500 m
        // beyond where the drive leads), with stamps a jump; the pose after it continues the
        // drive either way.
        for stamped in [false, true] {
            let mut c = Continuity::default();
            let ahead = |i: usize| Se2::new(0.0, 1.2 * i as f64, 0.0);
            for i in 0..100 {
                let glitch = i % 10 == 5;
                let published = if glitch {
                    Se2::new(0.0, 500.0, 0.0) * ahead(i)
                } else {
                    ahead(i)
                };
                let stamp = if stamped { i as f64 / 10.0 } else { f64::NAN };
                let got = c.observe(published, stamp, &params);
                match (glitch, stamped, got) {
                    (true, true, Continued::Jumped) | (false, _, Continued::Moved) => {}
                    (true, false, Continued::OverGap { beyond: [x, y] }) => {
                        assert!(
                            (x - 500.0).abs() < 1e-9 && y.abs() < 1e-9,
                            "pose {i}: {x} {y}"
                        )
                    }
                    _ => panic!("pose {i}: {got:?}"),
                }
                if !glitch {
                    assert!(close(c.last.unwrap().0, ahead(i)), "pose {i}");
                }
            }
        }
    }

    #[test]
    fn the_papers_method_takes_every_step_for_motion() {
        let params = Preset::KissIcp.params();
        let mut c = Continuity::default();
        c.observe(Se2::new(0.0, 500.0, 499.0), f64::NAN, &params);
        c.observe(Se2::new(0.0, 500.0, 500.0), f64::NAN, &params);
        assert_eq!(
            c.observe(Se2::new(3.0, 0.0, 0.0), f64::NAN, &params),
            Continued::Moved
        );
        assert_eq!(c.continued_from_odom, Se2::IDENTITY);
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 256, rng_seed: proptest::test_runner::RngSeed::Fixed(27), ..Default::default() })]
        /// Any drive a car can make (speed changing by at most a fifth a pose, up to the limit,
        /// turning as it likes) is no jump; the same drive whose odometry changes frame at one
        /// pose after its first step, moving it by more than 30 m, is flagged there and only
        /// there (stamped at 10 Hz: also where it lands ahead, where the drive would have gone
        /// on to, which without stamps reads as poses missing), and every pose after it lands
        /// where the unbroken drive's would, moved by the one predicted step's error.
        #[test]
        fn a_frame_change_is_found_and_undone(
            steps in proptest::collection::vec((0.8f64..1.2, -0.5f64..0.5), 20..200),
            at in 2usize..20,
            (yaw, dx, dy) in (-3.1f64..3.1, 20.0f64..5000.0, -5000.0f64..5000.0),
        ) {
            let params = Preset::KissIcp.robust_params();
            let mut drive = vec![Se2::new(0.2, 10.0, -3.0)];
            let mut speed = 3.0;
            for &(growth, turn) in &steps {
                speed = f64::min(speed * growth, 6.9);
                let last = drive[drive.len() - 1];
                drive.push(last * Se2::new(turn, speed, 0.0));
            }
            let stamp = |i: usize| i as f64 / 10.0;
            for stamped in [false, true] {
                let mut c = Continuity::default();
                for (i, pose) in drive.iter().enumerate() {
                    let stamp_s = if stamped { stamp(i) } else { f64::NAN };
                    proptest::prop_assert_eq!(c.observe(*pose, stamp_s, &params), Continued::Moved);
                }
            }
            let change = Se2::new(yaw, dx, dy);
            // A change that moves the pose it happens at less than a car's step and three times
            // more is no jump to anyone: only the others are asked for.
            let moved = |a: Se2, b: Se2| {
                let ([ax, ay], [bx, by]) = (a.translation(), b.translation());
                (ax - bx).hypot(ay - by)
            };
            proptest::prop_assume!(moved(change * drive[at], drive[at]) > 30.0);
            let mut c = Continuity::default();
            let mut landed = Vec::new();
            for (i, pose) in drive.iter().enumerate() {
                let published = if i < at { *pose } else { change * *pose };
                let expected = if i == at { Continued::Jumped } else { Continued::Moved };
                let got = c.observe(published, stamp(i), &params);
                proptest::prop_assert_eq!(got, expected, "pose {}", i);
                landed.push(c.last.unwrap().0);
            }
            // After the jump, the poses differ from the drive's by one fixed transform: the
            // prediction's error at the jumped pose.
            let error = landed[at] * drive[at].inverse();
            for i in at..drive.len() {
                let want = error * drive[i];
                let [gx, gy] = landed[i].translation();
                let [wx, wy] = want.translation();
                let off = (gx - wx).hypot(gy - wy);
                proptest::prop_assert!(off < 1e-6, "pose {}: {} m", i, off);
            }
        }

        /// Without stamps, poses missing from a drive (up to a second and a half of a 10 Hz
        /// odometry, anywhere after its first step) are motion: the drive's speed changing by
        /// at most 5 % a pose (5 m/s^2 at 10 Hz), its turn by at most 0.005 rad a pose up to
        /// 0.1 rad (entering and leaving bends), each step an arc.
        #[test]
        fn missing_poses_are_motion(
            steps in proptest::collection::vec((0.95f64..1.05, -0.005f64..0.005), 20..200),
            (from, missing) in (2usize..20, 2usize..16),
        ) {
            let params = Preset::KissIcp.robust_params();
            let mut drive = vec![Se2::new(-1.0, 300.0, 40.0)];
            let (mut speed, mut turn) = (4.0, 0.0);
            for &(growth, bend) in &steps {
                speed = (speed * growth).clamp(1.0, 6.9);
                turn = f64::clamp(turn + bend, -0.1, 0.1);
                let chord = Se2::new(turn, speed * (turn / 2.0).cos(), speed * (turn / 2.0).sin());
                let last = drive[drive.len() - 1];
                drive.push(last * chord);
            }
            proptest::prop_assume!(from + missing < drive.len());
            let mut c = Continuity::default();
            for (i, pose) in drive.iter().enumerate() {
                if (from..from + missing).contains(&i) {
                    continue;
                }
                let got = c.observe(*pose, f64::NAN, &params);
                if let Continued::OverGap { beyond: [x, y] } = got {
                    // Only the step over the gap, and it lies beyond the one step's prediction
                    // by less than the road missed.
                    proptest::prop_assert_eq!(i, from + missing);
                    proptest::prop_assert!(x.hypot(y) < 7.0 * missing as f64);
                } else {
                    proptest::prop_assert_eq!(got, Continued::Moved, "pose {}", i);
                }
            }
            proptest::prop_assert_eq!(c.continued_from_odom, Se2::IDENTITY);
        }
    }
}
