//! 3D poses (3x4 `[R | t]`) and the axis conventions odometry sources use.
//!
//! The corrector works in a planar, z-up frame (`flu`: x forward, y left, z up). A source whose
//! poses use another convention is converted at the edges: [`AxisConvention::to_planar`] on the
//! way in, [`AxisConvention::from_planar`] on the way out.

use crate::se2::Se2;

/// A rigid 3D pose `world_from_body` as a row-major 3x4 matrix `[R | t]` (translation in metres).
pub type Pose3 = [[f64; 4]; 3];

/// How a source's world and body axes are laid out.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum AxisConvention {
    /// x forward, y left, z up (ROS REP 103). Already planar.
    #[default]
    Flu,
    /// The KITTI camera: x right, y down, z forward.
    KittiCamera,
}

impl std::str::FromStr for AxisConvention {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "flu" => Ok(AxisConvention::Flu),
            "kitti-camera" => Ok(AxisConvention::KittiCamera),
            other => Err(format!(
                "unknown axis convention '{other}' (expected flu or kitti-camera)"
            )),
        }
    }
}

/// `flu_from_camera` for KITTI: camera z (forward) becomes x, camera x (right) becomes -y,
/// camera y (down) becomes -z.
const FLU_FROM_CAMERA: [[f64; 3]; 3] = [[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]];

fn mat3_mul(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut m = [[0.0; 3]; 3];
    for (i, row) in m.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j];
        }
    }
    m
}

fn transpose(a: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut m = [[0.0; 3]; 3];
    for (i, row) in m.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = a[j][i];
        }
    }
    m
}

/// `a * pose * b` for fixed rotations `a` and `b` (used to change axis conventions).
fn conjugate(a: &[[f64; 3]; 3], pose: &Pose3, b: &[[f64; 3]; 3]) -> Pose3 {
    let r = [
        [pose[0][0], pose[0][1], pose[0][2]],
        [pose[1][0], pose[1][1], pose[1][2]],
        [pose[2][0], pose[2][1], pose[2][2]],
    ];
    let r = mat3_mul(&mat3_mul(a, &r), b);
    let t = [pose[0][3], pose[1][3], pose[2][3]];
    let mut out = [[0.0; 4]; 3];
    for i in 0..3 {
        out[i][..3].copy_from_slice(&r[i]);
        out[i][3] = a[i][0] * t[0] + a[i][1] * t[1] + a[i][2] * t[2];
    }
    out
}

impl AxisConvention {
    /// Converts a pose of this convention into the planar `flu` convention (world and body).
    pub fn to_planar(self, pose: &Pose3) -> Pose3 {
        match self {
            AxisConvention::Flu => *pose,
            AxisConvention::KittiCamera => {
                conjugate(&FLU_FROM_CAMERA, pose, &transpose(&FLU_FROM_CAMERA))
            }
        }
    }

    /// Converts a planar `flu` pose back into this convention.
    pub fn from_planar(self, pose: &Pose3) -> Pose3 {
        match self {
            AxisConvention::Flu => *pose,
            AxisConvention::KittiCamera => {
                conjugate(&transpose(&FLU_FROM_CAMERA), pose, &FLU_FROM_CAMERA)
            }
        }
    }
}

/// The planar position (x, y in metres) of a planar pose.
pub fn planar_position(pose: &Pose3) -> [f64; 2] {
    [pose[0][3], pose[1][3]]
}

/// The heading (radians, counter-clockwise from x) of a planar pose's forward (body x) axis.
pub fn planar_heading(pose: &Pose3) -> f64 {
    pose[1][0].atan2(pose[0][0])
}

/// Applies a planar correction `corrected_from_odom` to a planar pose: x and y are moved by the
/// transform, the yaw gains its rotation angle, and z, roll and pitch are kept.
pub fn apply_planar_correction(corrected_from_odom: &Se2, pose: &Pose3) -> Pose3 {
    let (c, s) = corrected_from_odom.rotation();
    let [x, y] = corrected_from_odom.apply(planar_position(pose));
    let mut out = *pose;
    for j in 0..3 {
        out[0][j] = c * pose[0][j] - s * pose[1][j];
        out[1][j] = s * pose[0][j] + c * pose[1][j];
    }
    out[0][3] = x;
    out[1][3] = y;
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kitti_camera_round_trip_and_forward_axis() {
        // Camera moved 2 m forward (z) and 1 m right (x), yawed left by 0.3 rad about -y (up).
        let (s, c) = 0.3f64.sin_cos();
        let cam: Pose3 = [[c, 0.0, -s, 1.0], [0.0, 1.0, 0.0, 0.5], [s, 0.0, c, 2.0]];
        let planar = AxisConvention::KittiCamera.to_planar(&cam);
        assert_eq!(planar_position(&planar), [2.0, -1.0]);
        assert!((planar[2][3] + 0.5).abs() < 1e-15);
        // A left turn is a positive yaw in the z-up frame.
        assert!((planar_heading(&planar) - 0.3).abs() < 1e-12);
        let back = AxisConvention::KittiCamera.from_planar(&planar);
        for i in 0..3 {
            for j in 0..4 {
                assert!((back[i][j] - cam[i][j]).abs() < 1e-15);
            }
        }
    }

    #[test]
    fn planar_correction_keeps_z_and_adds_yaw() {
        let pose: Pose3 = [
            [1.0, 0.0, 0.0, 1.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 7.0],
        ];
        let corr = Se2::new(std::f64::consts::FRAC_PI_2, 10.0, 0.0);
        let out = apply_planar_correction(&corr, &pose);
        assert!((out[0][3] - 10.0).abs() < 1e-12 && (out[1][3] - 1.0).abs() < 1e-12);
        assert_eq!(out[2][3], 7.0);
        assert!((planar_heading(&out) - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    }
}
