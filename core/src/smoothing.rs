//! Smooth output: the published correction follows the corrector's exact `map_from_odom` at a
//! bounded rate, so that an accepted correction becomes a glide instead of a jump.
//!
//! The rate is bounded where it matters, at the current pose: from one pose to the next, the
//! output moves at most `max_step_m` and turns at most `max_yaw_step_rad` more than the odometry
//! itself did (as the scale estimate scales its steps, where the corrector estimates the scale:
//! [`crate::scale`]). The exact estimate is untouched; only what is published is smoothed. While the
//! vehicle stands still the published correction is held ([`Smoother::hold`]): a standing
//! vehicle's output does not creep.

use crate::se2::{wrap_angle, Se2};

/// Bounds on how fast the published correction may change.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Smoothing {
    /// Largest change of the output position per pose beyond the odometry's motion (metres).
    pub max_step_m: f64,
    /// Largest change of the output yaw per pose beyond the odometry's rotation (radians).
    pub max_yaw_step_rad: f64,
}

impl Default for Smoothing {
    /// 5 cm and 0.1 degree per pose.
    fn default() -> Self {
        Smoothing {
            max_step_m: 0.05,
            max_yaw_step_rad: 0.1_f64.to_radians(),
        }
    }
}

/// The smoothed correction of one source.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Smoother {
    limits: Smoothing,
    output_from_odom: Option<Se2>,
}

impl Smoother {
    /// A smoother that starts at the first exact correction it is given.
    pub fn new(limits: Smoothing) -> Self {
        Smoother {
            limits,
            output_from_odom: None,
        }
    }

    /// The last published correction (`None` before the first): the smoother's whole state.
    pub fn output_from_odom(&self) -> Option<Se2> {
        self.output_from_odom
    }

    /// A smoother that continues from a saved [`Smoother::output_from_odom`].
    pub fn restore(limits: Smoothing, output_from_odom: Option<Se2>) -> Self {
        Smoother {
            limits,
            output_from_odom,
        }
    }

    /// The correction to publish for the pose at `position_in_odom` (metres, the frame
    /// `map_from_odom` maps from), moved from the previous one toward the exact `map_from_odom`:
    /// the pose's output position moves by at most `max_step_m` and its yaw by at most
    /// `max_yaw_step_rad`. Once both remaining differences are within the limits it equals
    /// `map_from_odom` exactly.
    pub fn next(&mut self, map_from_odom: Se2, position_in_odom: [f64; 2]) -> Se2 {
        let Some(current) = self.output_from_odom else {
            self.output_from_odom = Some(map_from_odom);
            return map_from_odom;
        };
        let from = current.apply(position_in_odom);
        let to = map_from_odom.apply(position_in_odom);
        let d = [to[0] - from[0], to[1] - from[1]];
        let distance = d[0].hypot(d[1]);
        let turn = wrap_angle(map_from_odom.yaw() - current.yaw());
        let limits = self.limits;
        let next = if distance <= limits.max_step_m && turn.abs() <= limits.max_yaw_step_rad {
            map_from_odom
        } else {
            let f = (limits.max_step_m / distance).min(1.0);
            let position = [from[0] + d[0] * f, from[1] + d[1] * f];
            let yaw = current.yaw() + turn.clamp(-limits.max_yaw_step_rad, limits.max_yaw_step_rad);
            let rotated = Se2::new(yaw, 0.0, 0.0).apply(position_in_odom);
            Se2::new(yaw, position[0] - rotated[0], position[1] - rotated[1])
        };
        self.output_from_odom = Some(next);
        next
    }

    /// The correction to publish for a pose of a standing vehicle: the last one published,
    /// unchanged (the exact `map_from_odom` before the first), so that the output moves only as
    /// the odometry does and a glide waits until the vehicle moves again.
    pub fn hold(&mut self, map_from_odom: Se2) -> Se2 {
        *self.output_from_odom.get_or_insert(map_from_odom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_standing_vehicles_output_is_held_and_the_glide_goes_on_when_it_moves() {
        let mut s = Smoother::new(Smoothing::default());
        let target = Se2::new(0.0, 1.0, 0.0);
        assert_eq!(s.hold(Se2::IDENTITY), Se2::IDENTITY, "the first is exact");
        // 5 cm of the 1 m toward the target, then nothing while standing, then 5 cm more.
        let x = |t: Se2| t.translation()[0];
        let gliding = s.next(target, [1.0, 0.0]);
        assert!((x(gliding) - 0.05).abs() < 1e-12, "{gliding:?}");
        for _ in 0..100 {
            assert_eq!(s.hold(target), gliding);
        }
        let moving = s.next(target, [2.0, 0.0]);
        assert!((x(moving) - 0.1).abs() < 1e-12, "{moving:?}");
    }

    #[test]
    fn glides_to_a_jump_within_the_limits_then_follows_exactly() {
        let limits = Smoothing::default();
        let mut s = Smoother::new(limits);
        assert_eq!(s.next(Se2::IDENTITY, [0.0, 0.0]), Se2::IDENTITY);
        let target = Se2::new(0.02, 3.0, -4.0);
        let mut previous = Se2::IDENTITY;
        let mut steps = 0;
        for i in 1..1000 {
            let p = [i as f64, 0.5 * i as f64];
            let out = s.next(target, p);
            let moved = {
                let (a, b) = (previous.apply(p), out.apply(p));
                (a[0] - b[0]).hypot(a[1] - b[1])
            };
            assert!(moved <= limits.max_step_m + 1e-12, "step {i}: {moved}");
            let turned = wrap_angle(out.yaw() - previous.yaw()).abs();
            assert!(
                turned <= limits.max_yaw_step_rad + 1e-15,
                "step {i}: {turned}"
            );
            previous = out;
            if out == target {
                steps = i;
                break;
            }
        }
        // 5 m at 5 cm per pose and 1.15 degrees at 0.1 degree per pose: the distance decides.
        assert!((95..=105).contains(&steps), "reached after {steps} poses");
        assert_eq!(s.next(target, [5.0, 5.0]), target);
    }
}
