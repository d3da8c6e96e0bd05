//! The subcommands of `lanealign`.

pub mod correct;
pub mod demo;
pub mod eval;
pub mod params;
pub mod replay;
pub mod soak;

/// Percentile (0..1) of nanosecond samples, in microseconds.
pub fn percentile_us(sorted_ns: &[u64], q: f64) -> f64 {
    if sorted_ns.is_empty() {
        return f64::NAN;
    }
    sorted_ns[((sorted_ns.len() - 1) as f64 * q).round() as usize] as f64 / 1e3
}
