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
//! Only positions are judged. A heading can turn in one step in odometry that is not wrong (a
//! source that updates its heading less often than its position; the synthetic town's corners,
//! 90 degrees in one pose), and a turn taken for a jump would be lost for good; a jump of the
//! heading alone (an odometry restarted within a few metres of its origin) is left to the
//! alignment, which corrects heading. Without stamps, a gap in the poses (a file with poses
//! missing) reads as a jump when the missing road is longer than the speed limit allows in one
//! period and three times the step before, and the turn over the gap is then lost; stamps tell
//! a gap from a jump.
//!
//! Frames: `odom` is the source's planar odometry frame as it publishes it now; `continued` is
//! the frame of the session's first pose, which the corrector sees throughout.
//! `continued_from_odom` is the identity until the first jump.

use crate::params::Params;
use crate::pose::{apply_planar_correction, Pose3};
use crate::se2::Se2;

/// How many times longer than the step before a step must be to be a jump. A car
/// does not triple its speed between two poses: from the fastest step the speed limit allows at
/// the presets' rate (7 m at 10 Hz), the step before would have been at least 2.3 m (23 m/s).
pub const MAX_STEP_GROWTH: f64 = 3.0;

/// The length of a planar step (metres).
fn length(step: &Se2) -> f64 {
    let [dx, dy] = step.translation();
    dx.hypot(dy)
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
}

impl Default for Continuity {
    fn default() -> Self {
        Continuity {
            continued_from_odom: Se2::IDENTITY,
            last: None,
            last_motion: None,
        }
    }
}

/// How a pose continued the odometry.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Continued {
    /// A step the vehicle can drive.
    Moved,
    /// A jump: the pose was placed where the last motion leads.
    Jumped,
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
        let elapsed_s = (stamp_s - last_stamp_s).max(1.0 / params.odometry_rate_hz);
        let moved_m = length(&motion);
        // A step is a jump when the vehicle could not drive it in the time, and when it is
        // more than [`MAX_STEP_GROWTH`] times the step before: a source slower than its set
        // rate (poses far apart, all alike) is not one.
        if moved_m > params.max_speed_mps * elapsed_s
            && moved_m > MAX_STEP_GROWTH * length(&last_motion)
        {
            let predicted = last * last_motion;
            self.continued_from_odom = predicted * odom_from_body.inverse();
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
    use crate::se2::wrap_angle;

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
        // After a step of 1 m, 20 m in one period of 10 Hz is 200 m/s: a jump.
        let mut c = Continuity::default();
        c.observe(Se2::IDENTITY, f64::NAN, &params);
        c.observe(Se2::new(0.0, 1.0, 0.0), f64::NAN, &params);
        assert_eq!(
            c.observe(Se2::new(0.0, 21.0, 0.0), f64::NAN, &params),
            Continued::Jumped
        );
        // The same 20 m over a second the odometry paused (stamps 1 s apart) is 20 m/s: motion.
        let mut c = Continuity::default();
        c.observe(Se2::IDENTITY, 5.0, &params);
        c.observe(Se2::new(0.0, 1.0, 0.0), 5.1, &params);
        assert_eq!(
            c.observe(Se2::new(0.0, 21.0, 0.0), 6.1, &params),
            Continued::Moved
        );
        // A stamp that does not move forward, or moves less than one period of the set rate
        // (stamps in a unit too small), counts as one period.
        assert_eq!(
            c.observe(Se2::new(0.0, 100.0, 0.0), 6.1, &params),
            Continued::Jumped
        );
        assert_eq!(
            c.observe(Se2::new(0.0, 100.5, 0.0), 6.100_001, &params),
            Continued::Moved
        );
        assert_eq!(
            c.observe(Se2::new(0.0, 120.0, 0.0), 6.100_002, &params),
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
        /// there, and every pose after it lands where the unbroken drive's would, moved by the
        /// one predicted step's error.
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
            let mut c = Continuity::default();
            for pose in &drive {
                proptest::prop_assert_eq!(c.observe(*pose, f64::NAN, &params), Continued::Moved);
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
                let got = c.observe(published, f64::NAN, &params);
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
    }
}
