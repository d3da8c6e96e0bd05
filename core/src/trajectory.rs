//! Trajectory files: KITTI (12 numbers a line, row-major 3x4) and TUM (`t x y z qx qy qz qw`).

use std::path::{Path, PathBuf};
use std::str::FromStr;

use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::input::{quote, InputError, Lines};
use crate::number_text::push_separated;
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

/// How far a TUM quaternion's length may be from 1.
pub const MAX_QUATERNION_ERROR: f64 = 1e-3;

/// A trajectory file that could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum TrajectoryError {
    /// The file could not be read (not a regular file, a line too long, not text).
    #[error(transparent)]
    Input(#[from] InputError),
    /// The file could not be written.
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
                .map_err(|_| format!("'{}' is not a number", quote(tok)))?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(format!("'{}' is not finite", quote(tok)))
            }
        })
        .collect()
}

/// A line of `found` numbers where `format` has `expected`, with what the count suggests: the
/// other format's line, or a whole 4x4 matrix.
fn count_error(expected: usize, found: usize, format: Format) -> String {
    let hint = match (format, found) {
        (Format::Kitti, 8) => " (a TUM line: stamp, position, quaternion?)",
        (Format::Tum, 12) => " (a KITTI line: a 3x4 matrix by rows?)",
        (Format::Kitti, 16) => " (a whole 4x4 matrix? a KITTI line is its first three rows)",
        _ => "",
    };
    format!("expected {expected} numbers, found {found}{hint}")
}

/// One line: `None` for a blank line or a TUM comment, else the stamp (TUM) and the pose.
fn parse_line(line: &str, format: Format) -> Result<Option<(Option<f64>, Pose3)>, String> {
    let line = line.trim();
    if line.is_empty() || (format == Format::Tum && line.starts_with('#')) {
        return Ok(None);
    }
    if format == Format::Kitti && line.starts_with('#') {
        return Err("a comment, which KITTI files do not have (TUM files do)".into());
    }
    let v = numbers(line)?;
    let (stamp, pose) = match format {
        Format::Kitti => {
            let Ok(row_major) = <[f64; 12]>::try_from(v.as_slice()) else {
                return Err(count_error(12, v.len(), format));
            };
            (None, Pose3::from_row_major(&row_major))
        }
        Format::Tum => {
            if v.len() != 8 {
                return Err(count_error(8, v.len(), format));
            }
            let qn = (v[4] * v[4] + v[5] * v[5] + v[6] * v[6] + v[7] * v[7]).sqrt();
            if (qn - 1.0).abs() > MAX_QUATERNION_ERROR {
                return Err(format!("the quaternion has length {qn}, not 1"));
            }
            let pose = Pose3 {
                rotation: rotation_from_quaternion([v[4], v[5], v[6], v[7]]),
                translation: Vector3::new(v[1], v[2], v[3]),
            };
            (Some(v[0]), pose)
        }
    };
    if let Some(problem) = pose.problem() {
        return Err(problem);
    }
    Ok(Some((stamp, pose)))
}

/// What is wrong with timestamp `t` (seconds) after `last`, the one before it (`None` for the
/// first): a stamp is finite and later than the one before.
fn stamp_problem(last: Option<f64>, t: f64) -> Option<String> {
    if !t.is_finite() {
        return Some(format!("timestamp {t} is not finite"));
    }
    match last {
        Some(last) if t <= last => Some(format!(
            "timestamp {t} does not follow {last}: timestamps must increase"
        )),
        _ => None,
    }
}

/// The first of `stamps_s` (seconds, one per pose) that cannot time its pose, as a TUM file's
/// are checked: its index and what is wrong with it (not finite, or not later than the one
/// before). `None` when every stamp is fine.
pub fn stamps_problem(stamps_s: &[f64]) -> Option<(usize, String)> {
    let mut last = None;
    for (i, &t) in stamps_s.iter().enumerate() {
        if let Some(problem) = stamp_problem(last, t) {
            return Some((i, problem));
        }
        last = Some(t);
    }
    None
}

/// Parses numbered lines into a trajectory; `path` names the source in errors.
fn parse_lines<I>(lines: I, path: &Path, format: Format) -> Result<Trajectory, TrajectoryError>
where
    I: Iterator<Item = Result<(usize, String), InputError>>,
{
    let mut out = Trajectory {
        stamps: (format == Format::Tum).then(Vec::new),
        poses: Vec::new(),
    };
    for item in lines {
        let (line, text) = item?;
        let error = |reason: String| TrajectoryError::Parse {
            path: path.to_path_buf(),
            line,
            reason,
        };
        let Some((stamp, pose)) = parse_line(&text, format).map_err(error)? else {
            continue;
        };
        if let (Some(stamps), Some(t)) = (out.stamps.as_mut(), stamp) {
            if let Some(problem) = stamp_problem(stamps.last().copied(), t) {
                return Err(error(problem));
            }
            stamps.push(t);
        }
        out.poses.push(pose);
    }
    Ok(out)
}

/// Parses trajectory text (any bytes: lines that are not UTF-8 are refused); `path` only names
/// the source in errors. Lines are bounded as when reading a file.
pub fn parse(
    text: impl AsRef<[u8]>,
    path: &Path,
    format: Format,
) -> Result<Trajectory, TrajectoryError> {
    parse_lines(Lines::new(text.as_ref(), path), path, format)
}

/// Reads a trajectory file (a regular file; streamed, a bounded line at a time).
pub fn read(path: &Path, format: Format) -> Result<Trajectory, TrajectoryError> {
    parse_lines(Lines::open(path)?, path, format)
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
                push_separated(&mut s, &p.to_row_major(), ' ');
                s.push('\n');
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
                push_separated(&mut s, &[*t, x, y, z, q[0], q[1], q[2], q[3]], ' ');
                s.push('\n');
            }
        }
    }
    Ok(s)
}

/// Writes a trajectory file atomically (it appears whole or not at all).
pub fn write(path: &Path, traj: &Trajectory, format: Format) -> Result<(), TrajectoryError> {
    let text = format_text(traj, format, path)?;
    Ok(crate::input::write_atomic(path, text.as_bytes())?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kitti_round_trips_exactly() {
        let text = "1 0 0 0.1 0 1 0 -2.5e-3 0 0 1 3\n0.6 -0.8 0 1 0.8 0.6 0 2 0 0 1 3\n";
        let p = Path::new("x.txt");
        let t = parse(text, p, Format::Kitti).unwrap();
        assert_eq!(t.poses.len(), 2);
        let again = parse(format_text(&t, Format::Kitti, p).unwrap(), p, Format::Kitti).unwrap();
        assert_eq!(again, t);
    }

    #[test]
    fn tum_round_trips() {
        let text = "# t x y z qx qy qz qw\n1.5 1 2 3 0 0 0.3826834323650898 0.9238795325112867\n";
        let p = Path::new("x.tum");
        let t = parse(text, p, Format::Tum).unwrap();
        assert_eq!(t.stamps.as_deref(), Some(&[1.5][..]));
        assert!((t.poses[0].rotation[(1, 0)] - std::f64::consts::FRAC_1_SQRT_2).abs() < 1e-12);
        let again = parse(format_text(&t, Format::Tum, p).unwrap(), p, Format::Tum).unwrap();
        let (a, b) = (again.poses[0].to_row_major(), t.poses[0].to_row_major());
        assert!(a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-12));
    }

    #[test]
    fn stamps_are_checked_as_a_tum_file_checks_them() {
        assert_eq!(stamps_problem(&[]), None);
        assert_eq!(stamps_problem(&[-1.0, 0.0, 0.1]), None);
        assert_eq!(
            stamps_problem(&[0.0, 0.1, 0.1]),
            Some((
                2,
                "timestamp 0.1 does not follow 0.1: timestamps must increase".into()
            ))
        );
        assert_eq!(
            stamps_problem(&[0.0, f64::NAN, 0.2]),
            Some((1, "timestamp NaN is not finite".into()))
        );
        assert_eq!(
            stamps_problem(&[f64::INFINITY]),
            Some((0, "timestamp inf is not finite".into()))
        );
        let p = Path::new("x.tum");
        let refused = parse("1 0 0 0 0 0 0 1\n0.5 0 0 0 0 0 0 1\n", p, Format::Tum);
        assert!(
            matches!(&refused, Err(TrajectoryError::Parse { line: 2, reason, .. })
                if reason == "timestamp 0.5 does not follow 1: timestamps must increase"),
            "{refused:?}"
        );
    }

    #[test]
    fn bad_lines_name_file_and_line() {
        let p = Path::new("bad.txt");
        let cases = [
            (
                "1 0 0 0 0 1 0 0 0 0 1 0\n1 2 3\n",
                2,
                "expected 12 numbers, found 3",
            ),
            ("0 0 0 0 0 0 0 1\n", 1, "found 8 (a TUM line"),
            (
                "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n",
                1,
                "found 16 (a whole 4x4 matrix?",
            ),
            ("# timestamp tx ty tz qx qy qz qw\n", 1, "TUM files do"),
            ("1 0 0 0 0 1 0 0 0 0 1 x\n", 1, "not a number"),
            (
                "1 0 0 0 0 1 0 0 0 0 1 0\n\n1 0 0 nan 0 1 0 0 0 0 1 0\n",
                3,
                "not finite",
            ),
            ("1 0 0 inf 0 1 0 0 0 0 1 0\n", 1, "not finite"),
            (
                "1 0 0 1e308 0 1 0 0 0 0 1 0\n",
                1,
                "coordinate 1.000e308 m is beyond 1e7 m",
            ),
            ("0 0 0 0 0 0 0 0 0 0 0 0\n", 1, "degenerate"),
            ("1.01 0 0 0 0 1.01 0 0 0 0 1.01 0\n", 1, "not orthonormal"),
            ("1 0 0 0 0 1 0 0 0 0 -1 0\n", 1, "reflection"),
        ];
        for (text, line, what) in cases {
            let e = parse(text, p, Format::Kitti).unwrap_err();
            let msg = e.to_string();
            assert!(msg.starts_with(&format!("bad.txt:{line}:")), "{msg}");
            assert!(msg.contains(what), "{msg}");
        }
        let long_token = format!("{} 0 0 0 0 1 0 0 0 0 1 0\n", "9x".repeat(1000));
        let msg = parse(&long_token, p, Format::Kitti)
            .unwrap_err()
            .to_string();
        assert!(msg.contains("not a number") && msg.len() < 200, "{msg}");
        let tum = [
            ("1 0 0 0 0 0 0 2\n", "length 2"),
            ("1 0 0 0 0 1 0 0 0 0 1 0\n", "found 12 (a KITTI line"),
            ("1 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n", "must increase"),
        ];
        for (text, what) in tum {
            let msg = parse(text, p, Format::Tum).unwrap_err().to_string();
            assert!(msg.contains(what), "{msg}");
        }
    }

    #[test]
    fn real_odometry_precision_passes() {
        // A line of the shared stereo visual odometry run (six significant digits).
        let line = "0.999986 0.00533499 0.000398828 -0.0284618 -0.00533569 0.999984 0.00175901 -0.0367282 -0.000389438 -0.00176111 0.999998 1.54581\n";
        assert_eq!(
            parse(line, Path::new("vo.txt"), Format::Kitti)
                .unwrap()
                .poses
                .len(),
            1
        );
    }
}
