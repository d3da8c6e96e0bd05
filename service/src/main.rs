//! `lanealignd`: the drift correction daemon.

use std::io::IsTerminal;
use std::path::PathBuf;

use clap::{Parser, Subcommand};
use lanealign_service::config::LogFormat;
use lanealign_service::daemon;
use tracing_subscriber::EnvFilter;

#[derive(Parser)]
#[command(
    name = "lanealignd",
    version,
    about = "Odometry drift correction daemon (iceoryx2 shared memory)"
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    /// The configuration file (configs/lanealignd.toml documents every key).
    #[arg(long, global = true)]
    config: Option<PathBuf>,
    /// Log format, overriding the configuration: text or json.
    #[arg(long, global = true)]
    log_format: Option<LogFormat>,
}

#[derive(Subcommand)]
enum Command {
    /// Check the configuration and the tile with every rule the daemon applies, then exit.
    Check,
}

fn main() -> std::process::ExitCode {
    lanealign_core::report::exit_code(run(Cli::parse()))
}

fn run(cli: Cli) -> anyhow::Result<()> {
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    let Some(path) = cli.config else {
        anyhow::bail!("--config FILE is required");
    };
    let prepared = daemon::prepare(&path)?;
    let format = cli.log_format.unwrap_or(prepared.config.log_format);
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info"));
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal());
    match format {
        LogFormat::Json => builder.json().init(),
        LogFormat::Text => builder.init(),
    }
    match cli.command {
        Some(Command::Check) => {
            println!(
                "{}: ok: {} sources, namespace {}, {} {} ({} lanes, {} points; {})",
                path.display(),
                prepared.sources.len(),
                prepared.namespace,
                match prepared.lanes {
                    daemon::Lanes::Tile(_) => "tile",
                    daemon::Lanes::Grid { .. } => "grid",
                },
                prepared.config.tile.display(),
                prepared.tile.lanes,
                prepared.tile.points,
                prepared.tile.geometry,
            );
        }
        None => {
            let summaries = daemon::run(prepared)?;
            for (name, s) in summaries {
                tracing::info!(source = %name, received = s.received, published = s.published, "final");
            }
        }
    }
    Ok(())
}
