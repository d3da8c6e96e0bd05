//! Shared helpers for the end-to-end tests: where the real data lives.

use std::path::PathBuf;

/// `../shared/data` from the workspace root, or `LANEALIGN_DATA` when set; `None` (with a
/// message on stderr naming what is missing) when absent, so tests can skip cleanly.
pub fn shared_data() -> Option<PathBuf> {
    let dir = std::env::var_os("LANEALIGN_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"));
    if dir.join("kitti/poses/00.txt").is_file() {
        Some(dir)
    } else {
        eprintln!(
            "SKIPPED: real data not found at {} (set LANEALIGN_DATA to the shared data folder)",
            dir.display()
        );
        None
    }
}

/// The ten KITTI sequences with ground truth in the shared data.
pub const SEQUENCES: [&str; 10] = ["00", "01", "02", "04", "05", "06", "07", "08", "09", "10"];
