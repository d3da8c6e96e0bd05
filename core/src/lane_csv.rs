//! Lane polylines from CSV (`lane_id,x,y`; the rows of one lane contiguous and in driving order;
//! metres, already in the plane the corrector works in). The points are used as given: no
//! resampling, so point indices match the file's row order.

use std::path::{Path, PathBuf};

use crate::input::{quote, InputError, Lines};
use crate::lane_map::Lane;
use crate::pose::within_coordinate_bound;

/// A lane CSV that could not be read.
#[derive(Debug, thiserror::Error)]
pub enum LaneCsvError {
    /// The file could not be read (not a regular file, a line too long, not text).
    #[error(transparent)]
    Input(#[from] InputError),
    /// A row is malformed.
    #[error("{path}:{line}: {reason}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// The 1-based line number.
        line: usize,
        /// What is wrong.
        reason: String,
    },
}

/// The columns of a lane CSV, as its optional header names them (any case).
pub const HEADER: [&str; 3] = ["lane_id", "x", "y"];

/// Parses numbered lines of lane CSV; `path` names the source in errors.
fn parse_lines<I>(lines: I, path: &Path) -> Result<Vec<Lane>, LaneCsvError>
where
    I: Iterator<Item = Result<(usize, String), InputError>>,
{
    let mut lanes: Vec<Lane> = Vec::new();
    let mut seen = std::collections::HashSet::new();
    for item in lines {
        let (line_no, raw) = item?;
        let line = raw.trim();
        let error = |reason: String| LaneCsvError::Parse {
            path: path.to_path_buf(),
            line: line_no,
            reason,
        };
        if line_no == 1 && line.starts_with(|c: char| c.is_ascii_alphabetic()) {
            // A header: it must name the columns as they are read (`x,y,lane_id` was read as
            // lane ids from the x column, without a word).
            let names: Vec<String> = line.split(',').map(|n| n.trim().to_lowercase()).collect();
            if names != HEADER {
                return Err(error(format!(
                    "the header names the columns '{}': a lane CSV's are {}",
                    quote(line),
                    HEADER.join(",")
                )));
            }
            continue;
        }
        if line.is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        let [id, x, y] = fields[..] else {
            return Err(error(format!(
                "expected 3 fields (lane_id,x,y), found {}",
                fields.len()
            )));
        };
        let id: u64 = id.parse().map_err(|_| {
            error(format!(
                "lane id '{}' is not a whole number from 0 to {}",
                quote(id),
                u64::MAX
            ))
        })?;
        let coord = |s: &str| -> Result<f64, LaneCsvError> {
            match s.parse::<f64>() {
                Ok(v) if within_coordinate_bound(v) => Ok(v),
                _ => Err(error(format!(
                    "'{}' is not a finite number within 1e7 m",
                    quote(s)
                ))),
            }
        };
        let p = [coord(x)?, coord(y)?];
        match lanes.last_mut() {
            Some(lane) if lane.id == id => lane.points.push(p),
            _ => {
                if !seen.insert(id) {
                    return Err(error(format!(
                        "lane {id} continues after other lanes: its rows must be contiguous"
                    )));
                }
                lanes.push(Lane::new(id, vec![p]));
            }
        }
    }
    Ok(lanes)
}

/// Parses lane CSV text (any bytes; lines bounded, UTF-8 checked); `path` only names the source
/// in errors. A first line that begins with a letter is a header, which must name the columns
/// [`HEADER`].
pub fn parse(text: impl AsRef<[u8]>, path: &Path) -> Result<Vec<Lane>, LaneCsvError> {
    parse_lines(Lines::new(text.as_ref(), path), path)
}

/// Reads a lane CSV file (a regular file; streamed, a bounded line at a time).
pub fn read(path: &Path) -> Result<Vec<Lane>, LaneCsvError> {
    parse_lines(Lines::open(path)?, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_contiguous_lanes() {
        let lanes = parse("lane_id,x,y\n4,0,0\n4,3,0\n9,1,1\n", Path::new("l.csv")).unwrap();
        assert_eq!(lanes.len(), 2);
        assert_eq!(lanes[0].points, vec![[0.0, 0.0], [3.0, 0.0]]);
    }

    #[test]
    fn refuses_split_lanes_and_bad_numbers() {
        let e = parse("4,0,0\n5,0,0\n4,1,1\n", Path::new("l.csv")).unwrap_err();
        assert!(e.to_string().starts_with("l.csv:3:"), "{e}");
        let e = parse("4,0,nan\n", Path::new("l.csv")).unwrap_err();
        assert!(e.to_string().contains("finite"), "{e}");
        let e = parse("-1,0,0\n", Path::new("l.csv")).unwrap_err();
        assert_eq!(
            e.to_string(),
            "l.csv:1: lane id '-1' is not a whole number from 0 to 18446744073709551615"
        );
    }

    /// A header must name the columns as they are read: `x,y,lane_id` made lanes of the x
    /// column's values at (y, lane id), without a word.
    #[test]
    fn a_header_names_the_columns_as_they_are_read() {
        let e = parse("x,y,lane_id\n0,0,1\n5,0,1\n", Path::new("l.csv")).unwrap_err();
        assert_eq!(
            e.to_string(),
            "l.csv:1: the header names the columns 'x,y,lane_id': a lane CSV's are lane_id,x,y"
        );
        let e = parse("id,x,y\n1,0,0\n", Path::new("l.csv")).unwrap_err();
        assert!(e.to_string().contains("'id,x,y'"), "{e}");
        for header in ["lane_id,x,y", "Lane_ID, X, Y", ""] {
            let text = format!("{header}\n4,0,0\n4,3,0\n");
            let lanes = parse(&text, Path::new("l.csv")).unwrap();
            assert_eq!(lanes.len(), 1, "{header}");
            assert_eq!(lanes[0].points, vec![[0.0, 0.0], [3.0, 0.0]]);
        }
    }
}
