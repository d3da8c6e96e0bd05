//! The KITTI evaluation data of `../shared/data`: sequences and their anchors.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, Context};
use lanealign_core::geo::Anchor;

/// The KITTI odometry sequences with ground truth in the shared data (03 has no OSM extract).
pub const SEQUENCES: [&str; 10] = ["00", "01", "02", "04", "05", "06", "07", "08", "09", "10"];

/// `$LANEALIGN_DATA` when set, else `../shared/data` beside the workspace this was built in.
pub fn default_data_dir() -> PathBuf {
    std::env::var_os("LANEALIGN_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"))
}

/// The data directory of a tool's command line: `--data DIR` if given, else
/// [`default_data_dir`]; an error naming it when it holds no KITTI data.
pub fn data_dir_from_args(args: &[String]) -> anyhow::Result<PathBuf> {
    let data = args
        .iter()
        .position(|a| a == "--data")
        .and_then(|i| args.get(i + 1))
        .map(PathBuf::from)
        .unwrap_or_else(default_data_dir);
    if !data.join("kitti/georef.csv").is_file() {
        bail!("no KITTI data at {} (pass --data DIR)", data.display());
    }
    Ok(data)
}

/// Each sequence's anchor from `kitti/georef.csv`
/// (`seq,origin_lat,origin_lon,origin_alt,yaw_deg,east_m,north_m,fit_rmse_m`).
pub fn anchors(data: &Path) -> anyhow::Result<HashMap<String, Anchor>> {
    let path = data.join("kitti/georef.csv");
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    text.lines()
        .enumerate()
        .skip(1)
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            let f: Vec<&str> = l.split(',').collect();
            if f.len() < 7 {
                bail!("{}:{}: expected 8 fields", path.display(), i + 1);
            }
            let anchor: Anchor = format!("{},{},{},{},{}", f[1], f[2], f[4], f[5], f[6])
                .parse()
                .map_err(|e| anyhow::anyhow!("{}:{}: {e}", path.display(), i + 1))?;
            Ok((f[0].to_string(), anchor))
        })
        .collect()
}
