//! The daemon-facing subcommands of `lanealign`.

pub mod demo;
pub mod soak;

use std::path::Path;

use anyhow::Context;
use lanealign_core::geo::Anchor;

/// Percentile (0..1) of nanosecond samples, in microseconds.
pub fn percentile_us(sorted_ns: &[u64], q: f64) -> f64 {
    if sorted_ns.is_empty() {
        return f64::NAN;
    }
    sorted_ns[((sorted_ns.len() - 1) as f64 * q).round() as usize] as f64 / 1e3
}

/// Writes a daemon configuration with one source per `(name, pass_through)`.
pub fn write_config(
    path: &Path,
    tile: &Path,
    sources: &[(String, bool)],
    preset: &str,
    frame: &str,
    anchor: &Anchor,
) -> anyhow::Result<()> {
    let mut text = format!(
        "tile = {:?}\nmetrics_interval_s = 5.0\n",
        tile.display().to_string()
    );
    for (name, pass_through) in sources {
        text.push_str(&format!(
            "\n[[source]]\nname = \"{name}\"\npreset = \"{preset}\"\nframe = \"{frame}\"\npass_through = {pass_through}\n\
             anchor = {{ lat = {}, lon = {}, yaw_deg = {}, east_m = {}, north_m = {} }}\n",
            anchor.lat, anchor.lon, anchor.yaw_deg, anchor.east_m, anchor.north_m
        ));
    }
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}
