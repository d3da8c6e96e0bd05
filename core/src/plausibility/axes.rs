//! Whether poses move and stand as a vehicle does in their set axis convention.

use crate::pose::{AxisConvention, Pose3};

/// Largest share of a run's 3D path length that may go along the axis the planar frame drops
/// (vertical) before the axis convention is suspect. Measured on the 20 shared KITTI odometry
/// runs: 1.6 to 7.2 % in their own convention (24.6 % for the stereo VO of sequence 01, whose
/// height drifts), 41 to 100 % read in the other one.
pub const MAX_VERTICAL_SHARE: f64 = 0.33;

/// Shortest 3D path (metres) the axis and tilt checks judge: standing still proves nothing.
const MIN_PATH_FOR_AXIS_CHECK_M: f64 = 10.0;

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

/// A warning when `poses` (in `convention`) move or stand as no vehicle does, from one walk over
/// them: their motion looks like the other axis convention (more than [`MAX_VERTICAL_SHARE`] of
/// it vertical), or else they are tilted beyond [`MAX_TILT_DEG`] over more than
/// [`MAX_TILTED_SHARE`] of their path. A tilt names the axis convention in which they stand and
/// move as a vehicle's, where one does (the motion misses a camera's poses whose first metres
/// rise), and else quaternions written scalar first (TUM's order is `qx qy qz qw`). `None`
/// while the path is shorter than 10 m. The corrector moves the positions, so a tilt hardly
/// changes its corrections; the output's rotations are then wrong.
pub fn axes_warning(poses: &[Pose3], convention: AxisConvention) -> Option<String> {
    let motion = AxisMotion::of(poses);
    motion
        .warning(convention)
        .or_else(|| motion.tilt_warning(convention))
}

/// The path length of a stream of poses, how much of it goes along the vertical axis and how
/// much of it is driven tilted beyond [`MAX_TILT_DEG`], in every axis convention, pose by pose.
/// Its fields are what it has seen, to continue from later (a daemon's snapshot of a session).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AxisMotion {
    /// The last pose observed (in the set axis convention, metres).
    pub last: Option<Pose3>,
    /// Per convention of [`AxisConvention::ALL`]: metres along the vertical, metres in all.
    pub vertical_and_path_m: [(f64, f64); AxisConvention::ALL.len()],
    /// Per convention of [`AxisConvention::ALL`]: metres driven tilted beyond [`MAX_TILT_DEG`]
    /// (each step counted with the tilt of the pose it ends at).
    pub tilted_m: [f64; AxisConvention::ALL.len()],
}

impl AxisMotion {
    /// The motion of a whole run of poses.
    fn of(poses: &[Pose3]) -> AxisMotion {
        let mut motion = AxisMotion::default();
        poses.iter().for_each(|p| motion.observe(p));
        motion
    }

    pub(super) fn observe(&mut self, pose: &Pose3) {
        let Some(last) = self.last.replace(*pose) else {
            return;
        };
        let min_cos = MAX_TILT_DEG.to_radians().cos();
        let per_convention = self.vertical_and_path_m.iter_mut().zip(&mut self.tilted_m);
        for (c, ((vertical, path), tilted)) in AxisConvention::ALL.iter().zip(per_convention) {
            let planar = c.to_planar(pose);
            let d = planar.translation - c.to_planar(&last).translation;
            *vertical += d.z.abs();
            *path += d.norm();
            // The cosine of the tilt: how far the body's up axis points up in the world.
            if planar.rotation[(2, 2)] < min_cos {
                *tilted += d.norm();
            }
        }
    }

    /// The path length (metres).
    pub(super) fn path_m(&self) -> f64 {
        self.vertical_and_path_m[0].1
    }

    /// The share of the 3D path length that goes along `convention`'s vertical axis; `None`
    /// while the path is too short to tell.
    fn vertical_share(&self, convention: AxisConvention) -> Option<f64> {
        let k = AxisConvention::ALL.iter().position(|&c| c == convention)?;
        let (vertical, path) = self.vertical_and_path_m[k];
        (path.is_finite() && path >= MIN_PATH_FOR_AXIS_CHECK_M).then(|| vertical / path)
    }

    /// Whether the motion in `convention` goes along the vertical for at most
    /// [`MAX_VERTICAL_SHARE`] of the path, as a vehicle's does.
    fn moves_upright(&self, convention: AxisConvention) -> bool {
        self.vertical_share(convention)
            .is_some_and(|s| s <= MAX_VERTICAL_SHARE)
    }

    /// The share of the path driven tilted beyond [`MAX_TILT_DEG`] in `convention`; `None` while
    /// the path is too short to tell.
    fn tilted_share(&self, convention: AxisConvention) -> Option<f64> {
        let k = AxisConvention::ALL.iter().position(|&c| c == convention)?;
        let (_, path) = self.vertical_and_path_m[k];
        (path.is_finite() && path >= MIN_PATH_FOR_AXIS_CHECK_M).then(|| self.tilted_m[k] / path)
    }

    /// A warning when the poses in `convention` are tilted as no road vehicle drives, over more
    /// than [`MAX_TILTED_SHARE`] of the path ([`axes_warning`]). Where another convention has
    /// them move and stand as a vehicle does, that is named (a camera's poses whose first metres
    /// rise as they go); else the quaternions' order is suspect.
    pub(super) fn tilt_warning(&self, convention: AxisConvention) -> Option<String> {
        let share = self.tilted_share(convention)?;
        if share <= MAX_TILTED_SHARE {
            return None;
        }
        let better = other_convention(convention, |c| {
            self.moves_upright(c) && self.tilted_share(c).is_some_and(|s| s <= MAX_TILTED_SHARE)
        });
        let advice = match better {
            Some(c) => format!(
                "in the {} convention they stand and move as a vehicle's: {}",
                c.name(),
                try_frame(c)
            ),
            None => "if their rotations come from quaternions, were these written qw qx qy qz? \
                     (TUM's order is qx qy qz qw; the corrections hardly depend on the \
                     rotations, but the output's are the input's turned by them)"
                .to_string(),
        };
        Some(format!(
            "the poses are tilted more than {MAX_TILT_DEG:.0} degrees from upright on {:.0}% of \
             their path in the {} convention, as no road vehicle drives: {advice}",
            share * 100.0,
            convention.name()
        ))
    }

    /// A warning when the motion looks like another convention than `convention`.
    pub(super) fn warning(&self, convention: AxisConvention) -> Option<String> {
        let share = self.vertical_share(convention)?;
        if share <= MAX_VERTICAL_SHARE {
            return None;
        }
        let advice = match other_convention(convention, |c| self.moves_upright(c)) {
            Some(c) => try_frame(c),
            None => "check the poses' axis convention".to_string(),
        };
        Some(format!(
            "{:.0}% of the motion is vertical in the {} convention, which a vehicle does not do: \
             the poses probably use another axis convention; {advice}",
            share * 100.0,
            convention.name()
        ))
    }
}

/// The first axis convention other than `convention` of which `fits` holds.
fn other_convention(
    convention: AxisConvention,
    fits: impl Fn(AxisConvention) -> bool,
) -> Option<AxisConvention> {
    AxisConvention::ALL
        .into_iter()
        .find(|&c| c != convention && fits(c))
}

/// What to set to use axis convention `c`.
fn try_frame(c: AxisConvention) -> String {
    format!(
        "try --frame {} (frame = \"{}\" in a config)",
        c.name(),
        c.name()
    )
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::trajectory::{quaternion_from_rotation, rotation_from_quaternion};

    fn straight(convention: AxisConvention) -> Vec<Pose3> {
        (0..100)
            .map(|i| {
                let flu = Pose3::planar(i as f64, 0.02 * i as f64, 0.0, 0.01 * i as f64);
                convention.from_planar(&flu)
            })
            .collect()
    }

    #[test]
    fn a_camera_file_read_as_flu_is_noticed_and_the_fix_named() {
        let camera = straight(AxisConvention::KittiCamera);
        assert!(AxisMotion::of(&camera)
            .warning(AxisConvention::KittiCamera)
            .is_none());
        let w = AxisMotion::of(&camera)
            .warning(AxisConvention::Flu)
            .unwrap();
        assert!(w.contains("--frame kitti-camera"), "{w}");
        let flu = straight(AxisConvention::Flu);
        assert!(AxisMotion::of(&flu).warning(AxisConvention::Flu).is_none());
        assert!(AxisMotion::of(&flu[..3])
            .warning(AxisConvention::KittiCamera)
            .is_none());
    }

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
    pub(in crate::plausibility) fn scalar_first(pose: &Pose3) -> Pose3 {
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
            assert!(AxisMotion::of(&upright).tilt_warning(convention).is_none());
            let misread: Vec<Pose3> = upright.iter().map(scalar_first).collect();
            let w = AxisMotion::of(&misread)
                .tilt_warning(convention)
                .unwrap_or_else(|| panic!("no warning in {}", convention.name()));
            assert!(w.contains("written qw qx qy qz"), "{w}");
            // Too short a path proves nothing.
            assert!(AxisMotion::of(&misread[..5])
                .tilt_warning(convention)
                .is_none());
        }
        // A camera's poses read as `flu` are tilted too, and upright in their own axes.
        let camera = circle(AxisConvention::KittiCamera);
        let w = AxisMotion::of(&camera)
            .tilt_warning(AxisConvention::Flu)
            .unwrap_or_default();
        assert!(w.contains("try --frame kitti-camera"), "{w}");
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
        assert!(AxisMotion::of(&poses)
            .tilt_warning(AxisConvention::Flu)
            .is_none());
    }
}
