//! Writing daemon configurations (for `demo`, `soak` and the tests): the daemon's own typed
//! [`Config`], serialised with `toml`, so a written config always reads back.

use std::path::{Path, PathBuf};

use anyhow::Context;
use lanealign_core::geo::Anchor;
use lanealign_core::grid::LoadPolicy;
use lanealign_core::params::CorrectorConfig;
use lanealign_core::pose::AxisConvention;
use lanealign_service::config::{Config, LogFormat, SourceConfig};
use lanealign_wire::service::Namespace;
use lanealign_wire::wait::WaitStrategy;

/// The iceoryx2 namespace of one run of `command` (`demo`, `soak`) by process `pid`:
/// `<command>-<pid>`, its own so that the run can remove its files when done
/// ([`Namespace::remove_files`]).
pub fn run_namespace(command: &str, pid: u32) -> anyhow::Result<Namespace> {
    format!("{command}-{pid}")
        .parse()
        .with_context(|| format!("the namespace of `{command}`"))
}

/// One source of a generated configuration.
#[derive(Clone, Debug)]
pub struct Source {
    /// Its name.
    pub name: String,
    /// Its corrector.
    pub corrector: CorrectorConfig,
    /// Its axis convention.
    pub frame: AxisConvention,
    /// Its anchor.
    pub anchor: Anchor,
    /// Echo without correcting.
    pub pass_through: bool,
    /// How its worker waits for poses.
    pub wait: WaitStrategy,
}

/// A configuration for `tile` (a tile or a grid's folder) in `namespace` with `sources`, metrics every
/// `metrics_interval_s`, sessions journaled below `state_dir`.
pub fn config(
    tile: &Path,
    namespace: &str,
    metrics_interval_s: f64,
    state_dir: &Path,
    sources: &[Source],
) -> Config {
    Config {
        tile: PathBuf::from(tile),
        grid: LoadPolicy::default(),
        namespace: namespace.to_string(),
        metrics_interval_s,
        state_dir: Some(state_dir.to_path_buf()),
        journal: true,
        session_timeout_s: 600.0,
        max_sessions: 16,
        log_format: LogFormat::Text,
        trusted_tile_keys: Vec::new(),
        min_map_version: 0,
        cpu_dma_latency_us: None,
        sources: sources
            .iter()
            .map(|s| SourceConfig {
                name: s.name.clone(),
                frame: s.frame,
                anchor: s.anchor,
                pass_through: s.pass_through,
                corrector: s.corrector,
                wait: s.wait,
            })
            .collect(),
    }
}

/// Writes `config` to `path` as TOML.
pub fn write(path: &Path, config: &Config) -> anyhow::Result<()> {
    let text = toml::to_string(config).context("serialising the daemon configuration")?;
    std::fs::write(path, text).with_context(|| format!("writing {}", path.display()))
}
