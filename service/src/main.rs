//! `lanealignd`: the drift correction daemon.

use std::io::IsTerminal;
use std::path::PathBuf;

use clap::{Parser, Subcommand};
use lanealign_service::config::{Config, LogFormat};
use lanealign_service::daemon;
use tracing_subscriber::EnvFilter;

#[derive(Parser)]
#[command(
    name = "lanealignd",
    version,
    about = "Odometry drift correction daemon (iceoryx2)"
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    /// The configuration file.
    #[arg(long, global = true)]
    config: Option<PathBuf>,
    /// Log format, overriding the configuration: text or json.
    #[arg(long, global = true)]
    log_format: Option<String>,
}

#[derive(Subcommand)]
enum Command {
    /// Validate the configuration and the tile, then exit.
    Check,
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    let Some(path) = cli.config else {
        anyhow::bail!("--config FILE is required");
    };
    let (config, sources) = Config::load(&path)?;
    let format = match cli.log_format.as_deref() {
        None => config.log_format,
        Some("text") => LogFormat::Text,
        Some("json") => LogFormat::Json,
        Some(other) => anyhow::bail!("--log-format {other}: expected text or json"),
    };
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
            let (_, info) = lanealign_core::tile::load(&config.tile)?;
            println!(
                "{}: ok: {} sources, tile {} ({} lanes, {} points)",
                path.display(),
                sources.len(),
                config.tile.display(),
                info.lanes,
                info.points
            );
        }
        None => {
            let summaries = daemon::run(&config, sources)?;
            for (name, s) in summaries {
                tracing::info!(source = %name, received = s.received, published = s.published, "final");
            }
        }
    }
    Ok(())
}
