//! 3D poses and the axis conventions odometry sources use.
//!
//! The corrector works in a planar, z-up frame (`flu`: x forward, y left, z up). A source whose
//! poses use another convention is converted at the edges: [`AxisConvention::to_planar`] on the
//! way in, [`AxisConvention::from_planar`] on the way out. The 3D math is nalgebra's.

use nalgebra::{Matrix2, Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use crate::se2::Se2;

/// The largest coordinate a pose may have (metres): beyond it a pose is no odometry.
pub const MAX_COORDINATE_M: f64 = 1e7;

/// True for a coordinate (metres) a pose or a lane point may have: within
/// [`MAX_COORDINATE_M`] of the origin, so false for NaN and infinities too.
pub fn within_coordinate_bound(v: f64) -> bool {
    v.abs() <= MAX_COORDINATE_M
}

/// How far a rotation may be from orthonormal (largest entry of `|R^T R - I|`). Odometry files
/// print 6 to 7 significant digits: the shared stereo visual odometry run reaches 1.6e-5, so the
/// bound is 1e-4, well below what a scaled (1.01: 2e-2) or zero (1) matrix gives.
pub const MAX_ROTATION_ERROR: f64 = 1e-4;

/// A rigid 3D pose `world_from_body`: `point_in_world = rotation * point_in_body + translation`
/// (metres). Files and the wire store it as the 12 numbers of the row-major 3x4 matrix
/// `[R | t]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose3 {
    /// The rotation matrix `world_from_body` (as read: not re-orthonormalised).
    pub rotation: Matrix3<f64>,
    /// The body origin in the world frame (metres).
    pub translation: Vector3<f64>,
}

impl Pose3 {
    /// The identity pose.
    pub fn identity() -> Pose3 {
        Pose3 {
            rotation: Matrix3::identity(),
            translation: Vector3::zeros(),
        }
    }

    /// A pose from the row-major 3x4 matrix `[R | t]` (the KITTI and wire layout).
    pub fn from_row_major(v: &[f64; 12]) -> Pose3 {
        Pose3 {
            rotation: Matrix3::new(v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]),
            translation: Vector3::new(v[3], v[7], v[11]),
        }
    }

    /// The row-major 3x4 matrix `[R | t]`.
    pub fn to_row_major(&self) -> [f64; 12] {
        let (r, t) = (&self.rotation, &self.translation);
        [
            r[(0, 0)],
            r[(0, 1)],
            r[(0, 2)],
            t[0],
            r[(1, 0)],
            r[(1, 1)],
            r[(1, 2)],
            t[1],
            r[(2, 0)],
            r[(2, 1)],
            r[(2, 2)],
            t[2],
        ]
    }

    /// A planar pose at `(x, y)` (metres) heading `yaw` (radians, counter-clockwise from x),
    /// at height `z`.
    pub fn planar(x: f64, y: f64, yaw: f64, z: f64) -> Pose3 {
        let (s, c) = yaw.sin_cos();
        Pose3 {
            rotation: Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0),
            translation: Vector3::new(x, y, z),
        }
    }

    /// True when every number is finite.
    pub fn is_finite(&self) -> bool {
        self.rotation
            .iter()
            .chain(self.translation.iter())
            .all(|v| v.is_finite())
    }

    /// How far the rotation is from a proper rotation: the largest entry of `|R^T R - I|`, or
    /// infinity when `det R <= 0` (a reflection or a degenerate matrix).
    pub fn rotation_error(&self) -> f64 {
        if self.rotation.determinant() <= 0.0 {
            return f64::INFINITY;
        }
        let defect = self.rotation.transpose() * self.rotation - Matrix3::identity();
        defect.amax()
    }

    /// What makes this no pose, if anything: a non-finite number, a coordinate beyond
    /// [`MAX_COORDINATE_M`], or a rotation that is not proper and orthonormal within
    /// [`MAX_ROTATION_ERROR`].
    pub fn problem(&self) -> Option<String> {
        if !self.is_finite() {
            return Some("a number is not finite".into());
        }
        if let Some(v) = self
            .translation
            .iter()
            .find(|v| !within_coordinate_bound(**v))
        {
            return Some(format!("coordinate {v:.3e} m is beyond 1e7 m"));
        }
        let error = self.rotation_error();
        if error > MAX_ROTATION_ERROR {
            return Some(if error.is_finite() {
                format!("the rotation is not orthonormal (|R^T R - I| reaches {error:.1e})")
            } else {
                "the rotation is a reflection or degenerate (det R <= 0)".to_string()
            });
        }
        None
    }

    /// The planar position (x, y in metres) of a planar (`flu`) pose.
    pub fn planar_position(&self) -> [f64; 2] {
        [self.translation[0], self.translation[1]]
    }

    /// The heading (radians, counter-clockwise from x) of a planar pose's forward (body x) axis.
    pub fn planar_heading(&self) -> f64 {
        self.rotation[(1, 0)].atan2(self.rotation[(0, 0)])
    }

    /// The planar part of a planar pose as an SE(2) transform `world_from_body`.
    pub fn to_se2(&self) -> Se2 {
        let [x, y] = self.planar_position();
        Se2::new(self.planar_heading(), x, y)
    }
}

/// How a source's world and body axes are laid out.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum AxisConvention {
    /// x forward, y left, z up (ROS REP 103). Already planar.
    #[default]
    Flu,
    /// The KITTI camera: x right, y down, z forward.
    KittiCamera,
}

impl AxisConvention {
    /// Both conventions.
    pub const ALL: [AxisConvention; 2] = [AxisConvention::Flu, AxisConvention::KittiCamera];

    /// The name used on the command line and in configs.
    pub fn name(self) -> &'static str {
        match self {
            AxisConvention::Flu => "flu",
            AxisConvention::KittiCamera => "kitti-camera",
        }
    }
}

impl std::str::FromStr for AxisConvention {
    type Err = crate::names::NameError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        crate::names::parse_name(s)
    }
}

/// `flu_from_camera` for KITTI: camera z (forward) becomes x, camera x (right) becomes -y,
/// camera y (down) becomes -z.
fn flu_from_camera() -> Matrix3<f64> {
    Matrix3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0)
}

/// The pose expressed in axes rotated by `new_from_old` (world and body alike):
/// `new_from_old * pose * old_from_new`.
fn rotate_axes(new_from_old: &Matrix3<f64>, pose: &Pose3) -> Pose3 {
    Pose3 {
        rotation: new_from_old * pose.rotation * new_from_old.transpose(),
        translation: new_from_old * pose.translation,
    }
}

impl AxisConvention {
    /// Converts a pose of this convention into the planar `flu` convention (world and body).
    pub fn to_planar(self, pose: &Pose3) -> Pose3 {
        match self {
            AxisConvention::Flu => *pose,
            AxisConvention::KittiCamera => rotate_axes(&flu_from_camera(), pose),
        }
    }

    /// Converts a planar `flu` pose back into this convention.
    pub fn from_planar(self, pose: &Pose3) -> Pose3 {
        match self {
            AxisConvention::Flu => *pose,
            AxisConvention::KittiCamera => rotate_axes(&flu_from_camera().transpose(), pose),
        }
    }
}

/// Applies a planar correction `corrected_from_odom` to a planar pose: x and y are moved by the
/// transform, the yaw gains its rotation angle, and z, roll and pitch are kept (the rotation's
/// third row and the height are not touched).
pub fn apply_planar_correction(corrected_from_odom: &Se2, pose: &Pose3) -> Pose3 {
    let (c, s) = corrected_from_odom.rotation();
    let [x, y] = corrected_from_odom.apply(pose.planar_position());
    let turn = Matrix2::new(c, -s, s, c);
    let mut out = *pose;
    let top = turn * pose.rotation.fixed_rows::<2>(0);
    out.rotation.fixed_rows_mut::<2>(0).copy_from(&top);
    out.translation[0] = x;
    out.translation[1] = y;
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kitti_camera_round_trip_and_forward_axis() {
        // Camera moved 2 m forward (z) and 1 m right (x), yawed left by 0.3 rad about -y (up).
        let (s, c) = 0.3f64.sin_cos();
        let cam = Pose3::from_row_major(&[c, 0.0, -s, 1.0, 0.0, 1.0, 0.0, 0.5, s, 0.0, c, 2.0]);
        let planar = AxisConvention::KittiCamera.to_planar(&cam);
        assert_eq!(planar.planar_position(), [2.0, -1.0]);
        assert!((planar.translation[2] + 0.5).abs() < 1e-15);
        // A left turn is a positive yaw in the z-up frame.
        assert!((planar.planar_heading() - 0.3).abs() < 1e-12);
        let back = AxisConvention::KittiCamera.from_planar(&planar);
        let (a, b) = (back.to_row_major(), cam.to_row_major());
        assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-15));
    }

    #[test]
    fn planar_correction_keeps_z_and_adds_yaw() {
        let pose = Pose3::planar(1.0, 0.0, 0.0, 7.0);
        let corr = Se2::new(std::f64::consts::FRAC_PI_2, 10.0, 0.0);
        let out = apply_planar_correction(&corr, &pose);
        assert!((out.translation[0] - 10.0).abs() < 1e-12);
        assert!((out.translation[1] - 1.0).abs() < 1e-12);
        assert_eq!(out.translation[2], 7.0);
        assert_eq!(out.rotation.row(2), pose.rotation.row(2));
        assert!((out.planar_heading() - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    }

    #[test]
    fn row_major_layout_and_rotation_checks() {
        let v = [
            1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0,
        ];
        let p = Pose3::from_row_major(&v);
        assert_eq!(p.translation, Vector3::new(4.0, 8.0, 12.0));
        assert_eq!(p.rotation[(1, 2)], 7.0);
        assert_eq!(p.to_row_major(), v);
        assert!(Pose3::planar(1.0, 2.0, 0.4, 0.0).rotation_error() < 1e-15);
        let mut scaled = Pose3::identity();
        scaled.rotation *= 1.01;
        assert!(scaled.rotation_error() > 0.01);
        let mut mirrored = Pose3::identity();
        mirrored.rotation[(2, 2)] = -1.0;
        assert_eq!(mirrored.rotation_error(), f64::INFINITY);
        let zero = Pose3 {
            rotation: Matrix3::zeros(),
            ..Pose3::identity()
        };
        assert_eq!(zero.rotation_error(), f64::INFINITY);
    }

    #[test]
    fn convention_names_parse() {
        for c in AxisConvention::ALL {
            assert_eq!(c.name().parse::<AxisConvention>(), Ok(c));
        }
        let e = "kitti".parse::<AxisConvention>().unwrap_err().to_string();
        assert!(e.contains("kitti-camera"), "{e}");
    }
}
