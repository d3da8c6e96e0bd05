//! Whether poses move as a vehicle does in their set axis convention.

use crate::pose::{AxisConvention, Pose3};

/// Largest share of a run's 3D path length that may go along the axis the planar frame drops
/// (vertical) before the axis convention is suspect. Measured on the 20 shared KITTI odometry
/// runs: 1.6 to 7.2 % in their own convention (24.6 % for the stereo VO of sequence 01, whose
/// height drifts), 41 to 100 % read in the other one.
pub const MAX_VERTICAL_SHARE: f64 = 0.33;

/// Shortest 3D path (metres) the axis check judges: standing still proves nothing.
pub(super) const MIN_PATH_FOR_AXIS_CHECK_M: f64 = 10.0;

/// A warning when the motion of `poses` looks like the other axis convention.
pub fn axis_convention_warning(poses: &[Pose3], convention: AxisConvention) -> Option<String> {
    let mut motion = AxisMotion::default();
    poses.iter().for_each(|p| motion.observe(p));
    motion.warning(convention)
}

/// The path length of a stream of poses, and how much of it goes along the vertical axis, in
/// every axis convention, pose by pose. Its fields are what it has seen, to continue from
/// later (a daemon's snapshot of a session).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AxisMotion {
    /// The last pose observed (in the set axis convention, metres).
    pub last: Option<Pose3>,
    /// Per convention of [`AxisConvention::ALL`]: metres along the vertical, metres in all.
    pub vertical_and_path_m: [(f64, f64); AxisConvention::ALL.len()],
}

impl AxisMotion {
    pub(super) fn observe(&mut self, pose: &Pose3) {
        if let Some(last) = self.last.replace(*pose) {
            for (c, (vertical, path)) in AxisConvention::ALL
                .iter()
                .zip(&mut self.vertical_and_path_m)
            {
                let d = c.to_planar(pose).translation - c.to_planar(&last).translation;
                *vertical += d.z.abs();
                *path += d.norm();
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

    /// A warning when the motion looks like another convention than `convention`.
    pub(super) fn warning(&self, convention: AxisConvention) -> Option<String> {
        let share = self.vertical_share(convention)?;
        if share <= MAX_VERTICAL_SHARE {
            return None;
        }
        let better = AxisConvention::ALL
            .into_iter()
            .filter(|&c| c != convention)
            .find(|&c| {
                self.vertical_share(c)
                    .is_some_and(|s| s <= MAX_VERTICAL_SHARE)
            });
        let advice = match better {
            Some(c) => format!(
                "try --frame {} (frame = \"{}\" in a config)",
                c.name(),
                c.name()
            ),
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

#[cfg(test)]
mod tests {
    use super::*;

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
        assert!(axis_convention_warning(&camera, AxisConvention::KittiCamera).is_none());
        let w = axis_convention_warning(&camera, AxisConvention::Flu).unwrap();
        assert!(w.contains("--frame kitti-camera"), "{w}");
        let flu = straight(AxisConvention::Flu);
        assert!(axis_convention_warning(&flu, AxisConvention::Flu).is_none());
        assert!(axis_convention_warning(&flu[..3], AxisConvention::KittiCamera).is_none());
    }
}
