//! Trajectory files: KITTI (12 numbers a line, row-major 3x4) and TUM (`t x y z qx qy qz qw`).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::pose::Pose3;

/// A trajectory file format.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Format {
    /// KITTI: one pose a line, the 12 numbers of a row-major 3x4 matrix. No timestamps.
    #[default]
    Kitti,
    /// TUM: `timestamp x y z qx qy qz qw` (seconds, metres, unit quaternion); `#` comments.
    Tum,
}

impl Format {
    /// The format's name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Format::Kitti => "kitti",
            Format::Tum => "tum",
        }
    }
}

impl FromStr for Format {
    type Err = crate::names::NameError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        crate::names::parse_name(s)
    }
}

/// A sequence of poses, with timestamps (seconds) when the format has them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Trajectory {
    /// Timestamps in seconds, one per pose (TUM), or `None` (KITTI).
    pub stamps: Option<Vec<f64>>,
    /// The poses, in the file's own axis convention.
    pub poses: Vec<Pose3>,
}

/// A trajectory file that could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum TrajectoryError {
    /// The file could not be opened, read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A line is malformed.
    #[error("{path}:{line}: {reason}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The 1-based line number.
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// TUM output needs timestamps the trajectory does not have.
    #[error("{path}: TUM output needs timestamps, and the trajectory has none")]
    NoStamps {
        /// The file.
        path: PathBuf,
    },
}

/// The rotation matrix of a quaternion `(x, y, z, w)` (normalised first; nalgebra).
pub fn rotation_from_quaternion(q: [f64; 4]) -> Matrix3<f64> {
    UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[0], q[1], q[2]))
        .to_rotation_matrix()
        .into_inner()
}

/// The unit quaternion `(x, y, z, w)` of a rotation matrix, with `w >= 0` (nalgebra).
pub fn quaternion_from_rotation(r: &Matrix3<f64>) -> [f64; 4] {
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(*r));
    let [x, y, z, w] = [q.i, q.j, q.k, q.w];
    if w < 0.0 {
        [-x, -y, -z, -w]
    } else {
        [x, y, z, w]
    }
}

fn numbers(line: &str) -> Result<Vec<f64>, String> {
    line.split_whitespace()
        .map(|tok| {
            let v: f64 = tok
                .parse()
                .map_err(|_| format!("'{tok}' is not a number"))?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(format!("'{tok}' is not finite"))
            }
        })
        .collect()
}

/// Parses trajectory text; `path` only names the source in errors.
pub fn parse(text: &str, path: &Path, format: Format) -> Result<Trajectory, TrajectoryError> {
    let mut out = Trajectory {
        stamps: (format == Format::Tum).then(Vec::new),
        poses: Vec::new(),
    };
    let error = |line: usize, reason: String| TrajectoryError::Parse {
        path: path.to_path_buf(),
        line,
        reason,
    };
    for (k, raw) in text.lines().enumerate() {
        let line = raw.trim();
        if line.is_empty() || (format == Format::Tum && line.starts_with('#')) {
            continue;
        }
        let v = numbers(line).map_err(|r| error(k + 1, r))?;
        match format {
            Format::Kitti => {
                if v.len() != 12 {
                    return Err(error(
                        k + 1,
                        format!("expected 12 numbers, found {}", v.len()),
                    ));
                }
                let mut row_major = [0.0; 12];
                row_major.copy_from_slice(&v);
                out.poses.push(Pose3::from_row_major(&row_major));
            }
            Format::Tum => {
                if v.len() != 8 {
                    return Err(error(
                        k + 1,
                        format!("expected 8 numbers, found {}", v.len()),
                    ));
                }
                let qn = (v[4] * v[4] + v[5] * v[5] + v[6] * v[6] + v[7] * v[7]).sqrt();
                if qn < 1e-9 {
                    return Err(error(k + 1, "the quaternion has zero length".to_string()));
                }
                out.poses.push(Pose3 {
                    rotation: rotation_from_quaternion([v[4], v[5], v[6], v[7]]),
                    translation: Vector3::new(v[1], v[2], v[3]),
                });
                if let Some(stamps) = out.stamps.as_mut() {
                    stamps.push(v[0]);
                }
            }
        }
    }
    Ok(out)
}

/// Reads a trajectory file.
pub fn read(path: &Path, format: Format) -> Result<Trajectory, TrajectoryError> {
    let text = std::fs::read_to_string(path).map_err(|source| TrajectoryError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse(&text, path, format)
}

/// Formats a trajectory; numbers are written with the shortest text that reads back exactly.
pub fn format_text(
    traj: &Trajectory,
    format: Format,
    path: &Path,
) -> Result<String, TrajectoryError> {
    let mut s = String::with_capacity(traj.poses.len() * 200);
    match format {
        Format::Kitti => {
            for p in &traj.poses {
                let row: Vec<String> = p.to_row_major().iter().map(|v| format!("{v}")).collect();
                let _ = writeln!(s, "{}", row.join(" "));
            }
        }
        Format::Tum => {
            let stamps = traj
                .stamps
                .as_ref()
                .ok_or_else(|| TrajectoryError::NoStamps {
                    path: path.to_path_buf(),
                })?;
            for (t, p) in stamps.iter().zip(&traj.poses) {
                let q = quaternion_from_rotation(&p.rotation);
                let [x, y, z] = [p.translation[0], p.translation[1], p.translation[2]];
                let _ = writeln!(s, "{t} {x} {y} {z} {} {} {} {}", q[0], q[1], q[2], q[3]);
            }
        }
    }
    Ok(s)
}

/// Writes a trajectory file.
pub fn write(path: &Path, traj: &Trajectory, format: Format) -> Result<(), TrajectoryError> {
    let text = format_text(traj, format, path)?;
    std::fs::write(path, text).map_err(|source| TrajectoryError::Io {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kitti_round_trips_exactly() {
        let text = "1 0 0 0.1 0 1 0 -2.5e-3 0 0 1 3\n0.5 0 0 1 0 1 0 2 0 0 1 3\n";
        let p = Path::new("x.txt");
        let t = parse(text, p, Format::Kitti).unwrap();
        assert_eq!(t.poses.len(), 2);
        let again = parse(
            &format_text(&t, Format::Kitti, p).unwrap(),
            p,
            Format::Kitti,
        )
        .unwrap();
        assert_eq!(again, t);
    }

    #[test]
    fn tum_round_trips() {
        let text = "# t x y z qx qy qz qw\n1.5 1 2 3 0 0 0.3826834323650898 0.9238795325112867\n";
        let p = Path::new("x.tum");
        let t = parse(text, p, Format::Tum).unwrap();
        assert_eq!(t.stamps.as_deref(), Some(&[1.5][..]));
        assert!((t.poses[0].rotation[(1, 0)] - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-12);
        let again = parse(&format_text(&t, Format::Tum, p).unwrap(), p, Format::Tum).unwrap();
        let (a, b) = (again.poses[0].to_row_major(), t.poses[0].to_row_major());
        assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-12));
    }

    #[test]
    fn bad_lines_name_file_and_line() {
        let p = Path::new("bad.txt");
        let cases = [
            ("1 0 0 0 0 1 0 0 0 0 1 0\n1 2 3\n", 2, "expected 12"),
            ("1 0 0 0 0 1 0 0 0 0 1 x\n", 1, "not a number"),
            (
                "1 0 0 0 0 1 0 0 0 0 1 0\n\n1 0 0 nan 0 1 0 0 0 0 1 0\n",
                3,
                "not finite",
            ),
            ("1 0 0 inf 0 1 0 0 0 0 1 0\n", 1, "not finite"),
        ];
        for (text, line, what) in cases {
            let e = parse(text, p, Format::Kitti).unwrap_err();
            let msg = e.to_string();
            assert!(msg.starts_with(&format!("bad.txt:{line}:")), "{msg}");
            assert!(msg.contains(what), "{msg}");
        }
    }
}
