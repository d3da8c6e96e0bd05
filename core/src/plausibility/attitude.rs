//! Whether poses stand upright as a road vehicle does.

use crate::plausibility::axes::MIN_PATH_FOR_AXIS_CHECK_M;
use crate::pose::{AxisConvention, Pose3};

/// Tilt from upright (degrees) beyond which a pose is not a road vehicle's. Measured on the 30
/// shared KITTI trajectories (ground truth and both odometry runs): at most 10 degrees, but 42 for
/// the stereo VO of sequence 01, whose attitude drifts where it loses track; every pose of them
/// read from quaternions written `qw qx qy qz` is tilted 138-180 degrees.
pub const MAX_TILT_DEG: f64 = 60.0;

/// Largest share of a run's path length driven tilted beyond [`MAX_TILT_DEG`] before the
/// rotations are suspect. A vehicle's quaternions read in the wrong order tilt it by 180 degrees
/// less its heading (in `flu`), so a drive in every direction is tilted beyond 60 degrees on two
/// thirds of its path; in `kitti-camera` it is upside down throughout.
pub const MAX_TILTED_SHARE: f64 = 0.5;

/// A warning when `poses` (in `convention`) are tilted beyond [`MAX_TILT_DEG`] over more than
/// [`MAX_TILTED_SHARE`] of their path: their rotations are not a road vehicle's, most often
/// because quaternions were written scalar first (TUM's order is `qx qy qz qw`). `None` while
/// the path is shorter than 10 m, where standing still proves nothing. The corrector moves the
/// positions only, so its corrections hardly change; the output's rotations are then wrong.
pub fn tilt_warning(poses: &[Pose3], convention: AxisConvention) -> Option<String> {
    let min_cos = MAX_TILT_DEG.to_radians().cos();
    let (mut tilted_m, mut path_m) = (0.0, 0.0);
    for pair in poses.windows(2) {
        let step = (pair[1].translation - pair[0].translation).norm();
        // The cosine of the tilt: how far the body's up axis points up in the world.
        let up = convention.to_planar(&pair[1]).rotation[(2, 2)];
        if !(step.is_finite() && up.is_finite()) {
            continue;
        }
        path_m += step;
        if up < min_cos {
            tilted_m += step;
        }
    }
    let share = tilted_m / path_m;
    (path_m >= MIN_PATH_FOR_AXIS_CHECK_M && share > MAX_TILTED_SHARE).then(|| {
        format!(
            "the poses are tilted more than {MAX_TILT_DEG:.0} degrees from upright on {:.0}% of \
             their path in the {} convention, as no road vehicle drives: if their rotations come \
             from quaternions, were these written qw qx qy qz? (TUM's order is qx qy qz qw; the \
             corrections hardly depend on the rotations, but the output's are the input's turned \
             by them)",
            share * 100.0,
            convention.name()
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trajectory::{quaternion_from_rotation, rotation_from_quaternion};

    /// A drive around a circle of 50 m radius, every heading once, in `convention`.
    fn circle(convention: AxisConvention) -> Vec<Pose3> {
        (0..360)
            .map(|deg| {
                let heading = f64::from(deg).to_radians();
                let (x, y) = (50.0 * heading.sin(), 50.0 - 50.0 * heading.cos());
                convention.from_planar(&Pose3::planar(x, y, heading, 0.0))
            })
            .collect()
    }

    /// `pose` as read from a TUM line whose quaternion was written `qw qx qy qz`.
    fn scalar_first(pose: &Pose3) -> Pose3 {
        let [x, y, z, w] = quaternion_from_rotation(&pose.rotation);
        Pose3 {
            rotation: rotation_from_quaternion([w, x, y, z]),
            translation: pose.translation,
        }
    }

    #[test]
    fn quaternions_written_scalar_first_are_noticed_in_either_convention() {
        for convention in AxisConvention::ALL {
            let upright = circle(convention);
            assert!(tilt_warning(&upright, convention).is_none());
            let misread: Vec<Pose3> = upright.iter().map(scalar_first).collect();
            let w = tilt_warning(&misread, convention)
                .unwrap_or_else(|| panic!("no warning in {}", convention.name()));
            assert!(w.contains("written qw qx qy qz"), "{w}");
            // Too short a path proves nothing.
            assert!(tilt_warning(&misread[..5], convention).is_none());
        }
    }

    #[test]
    fn a_steep_street_is_no_tilt() {
        // 25 degrees of pitch (a 47 % grade, steeper than any street) all the way.
        let pitch = 25f64.to_radians();
        let poses: Vec<Pose3> = (0..100)
            .map(|i| {
                let mut p = Pose3::planar(f64::from(i), 0.0, 0.0, 0.0);
                p.rotation = nalgebra::Rotation3::from_euler_angles(0.0, -pitch, 0.0).into_inner();
                p.translation.z = f64::from(i) * pitch.tan();
                p
            })
            .collect();
        assert!(tilt_warning(&poses, AxisConvention::Flu).is_none());
    }
}
