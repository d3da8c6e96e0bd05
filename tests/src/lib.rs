//! What the end-to-end tests share: where the real data lives, and what happens when it is
//! absent. A test that needs `../shared/data` calls [`shared_data`]: without the data it says
//! `SKIPPED` on the terminal (past the test harness's output capture) and returns `None`, unless
//! `LANEALIGN_REQUIRE_DATA=1` (set by `.ci/run` wherever the data exists), where it fails.

use std::io::Write;
use std::path::{Path, PathBuf};

use lanealign_core::geo::Anchor;

/// The ten KITTI sequences with ground truth in the shared data.
pub const SEQUENCES: [&str; 10] = ["00", "01", "02", "04", "05", "06", "07", "08", "09", "10"];

/// `$LANEALIGN_DATA`, else `../shared/data` beside the workspace.
pub fn data_dir() -> PathBuf {
    std::env::var_os("LANEALIGN_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"))
}

/// The shared data folder, or `None` (with a visible `SKIPPED` line) when it is absent.
///
/// # Panics
/// When the data is absent and `LANEALIGN_REQUIRE_DATA=1`: a test must not pass without it.
pub fn shared_data() -> Option<PathBuf> {
    let dir = data_dir();
    if dir.join("kitti/poses/00.txt").is_file() {
        return Some(dir);
    }
    let test = std::thread::current()
        .name()
        .unwrap_or("a test")
        .to_string();
    if std::env::var("LANEALIGN_REQUIRE_DATA").is_ok_and(|v| v == "1") {
        panic!(
            "{test} needs the shared data, which is not at {} (LANEALIGN_REQUIRE_DATA=1)",
            dir.display()
        );
    }
    // Straight to the terminal: the harness captures eprintln! of passing tests.
    let _ = writeln!(
        std::io::stderr(),
        "SKIPPED {test}: no shared data at {} (set LANEALIGN_DATA)",
        dir.display()
    );
    None
}

/// Where KITTI sequence `name`'s odometry frame lies on Earth (`kitti/georef.csv` in `data`).
///
/// # Panics
/// When the file or the sequence's line is missing or malformed: the shared data is broken.
pub fn kitti_anchor(data: &Path, name: &str) -> Anchor {
    let georef = std::fs::read_to_string(data.join("kitti/georef.csv")).unwrap();
    let line = georef
        .lines()
        .find(|l| l.starts_with(&format!("{name},")))
        .unwrap();
    let f: Vec<&str> = line.split(',').collect();
    format!("{},{},{},{},{}", f[1], f[2], f[4], f[5], f[6])
        .parse()
        .unwrap()
}
