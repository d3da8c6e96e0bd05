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
}

impl Effective {
    /// The effective form of `config` (validated).
    pub fn of(config: CorrectorConfig) -> anyhow::Result<Effective> {
        Ok(Effective {
            params: config.params()?,
            unmarked_offset_scale: config.unmarked_offset_scale(),
            corrector: config,
        })
    }
}

/// Prints the configuration and every effective parameter as TOML (what `correct` with the
/// same flags runs, and what a daemon source with the same `corrector` table runs).
pub fn run(args: &ParamsArgs) -> anyhow::Result<()> {
    let effective = Effective::of(args.corrector.config()?)?;
    print!("{}", toml::to_string(&effective)?);
    Ok(())
}
