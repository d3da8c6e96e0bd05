//! Starting corpora for the cargo-fuzz targets in `fuzz/`: per target, the seeds the stable
//! mutator starts from and the regression cases its harness reads, with the target's dictionary
//! in libFuzzer's format. Without them a coverage-guided run starts from the regression files
//! alone, and three targets (`grid_cell`, `lanelet2`, `lane_csv`) have none.

use std::fmt::Write as _;
use std::path::Path;

use crate::regressions;
use crate::targets::Target;

/// What [`write_all`] wrote for one target.
pub struct Written {
    /// The target.
    pub target: Target,
    /// How many inputs its corpus folder holds.
    pub inputs: usize,
    /// Whether a dictionary was written beside the folder (targets without tokens get none).
    pub dictionary: bool,
}

/// Writes, for every target, `dir/<target>/` (`seed-<i>` for each seed and each regression case
/// of the target under its own name) and, where the target has tokens, `dir/<target>.dict`.
pub fn write_all(dir: &Path) -> std::io::Result<Vec<Written>> {
    let regressions = regressions::cases();
    Target::ALL
        .into_iter()
        .map(|target| {
            let folder = dir.join(target.name());
            std::fs::create_dir_all(&folder)?;
            let mut inputs = 0;
            for (i, seed) in target.seeds().iter().enumerate() {
                std::fs::write(folder.join(format!("seed-{i}")), seed)?;
                inputs += 1;
            }
            for case in regressions.iter().filter(|c| c.target == target) {
                std::fs::write(folder.join(case.name), &case.bytes)?;
                inputs += 1;
            }
            let tokens = target.dictionary();
            if !tokens.is_empty() {
                std::fs::write(
                    dir.join(format!("{}.dict", target.name())),
                    dictionary(tokens),
                )?;
            }
            Ok(Written {
                target,
                inputs,
                dictionary: !tokens.is_empty(),
            })
        })
        .collect()
}

/// `tokens` as a libFuzzer dictionary: one quoted token a line, with `\\`, `\"` and every byte
/// outside printable ASCII escaped as `\xNN`.
pub fn dictionary(tokens: &[&[u8]]) -> String {
    let mut text = String::new();
    for token in tokens {
        text.push('"');
        for &b in *token {
            match b {
                b'\\' => text.push_str("\\\\"),
                b'"' => text.push_str("\\\""),
                b' '..=b'~' => text.push(char::from(b)),
                _ => {
                    let _ = write!(text, "\\x{b:02X}");
                }
            }
        }
        text.push_str("\"\n");
    }
    text
}
