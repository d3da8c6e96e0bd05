//! `lanealign params`: the effective corrector parameters, as TOML.

use clap::Args;
use lanealign_core::params::{CorrectorConfig, Params};
use serde::Serialize;

use super::correct::CorrectorArgs;

/// The `lanealign params` arguments: the same corrector flags as `correct`.
#[derive(Args)]
pub struct ParamsArgs {
    #[command(flatten)]
    corrector: CorrectorArgs,
}

/// A corrector configuration with everything it resolves to.
#[derive(Serialize)]
pub struct Effective {
    /// The configuration as given (a daemon source's `corrector` table).
    pub corrector: CorrectorConfig,
    /// The unmarked-street offset scale the lanes must have.
    pub unmarked_offset_scale: f64,
    /// Every parameter after the preset, the method and the overrides.
    pub params: Params,
    /// The pose counts the parameters come to at the source's rate.
    pub at_rate: AtRate,
}

impl Effective {
    /// The effective form of `config` (validated).
    pub fn of(config: CorrectorConfig) -> anyhow::Result<Effective> {
        let params = config.params()?;
        Ok(Effective {
            at_rate: AtRate::of(&params),
            params,
            unmarked_offset_scale: config.unmarked_offset_scale(),
            corrector: config,
        })
    }
}

/// The presets' pose counts (chosen for 10 Hz odometry) as the corrector uses them at the
/// source's `odometry_rate_hz`.
#[derive(Serialize)]
pub struct AtRate {
    /// Every how many of the source's poses enters the window (above 10 Hz).
    pub window_stride: usize,
    /// `min_window` in the window's poses (scaled down below 10 Hz).
    pub min_window: usize,
    /// `max_window` in the window's poses (scaled down below 10 Hz).
    pub max_window: usize,
    /// `max_failures` (scaled down below 10 Hz).
    pub max_failures: u32,
}

impl AtRate {
    /// The counts of `params`.
    pub fn of(params: &Params) -> AtRate {
        AtRate {
            window_stride: params.window_stride(),
            min_window: params.min_window_poses(),
            max_window: params.max_window_poses(),
            max_failures: params.max_failures_at_rate(),
        }
    }
}

/// Prints the configuration and every effective parameter as TOML (what `correct` with the
/// same flags runs, and what a daemon source with the same `corrector` table runs).
pub fn run(args: &ParamsArgs) -> anyhow::Result<()> {
    let effective = Effective::of(args.corrector.config()?)?;
    print!("{}", toml::to_string(&effective)?);
    Ok(())
}
