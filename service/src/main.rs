//! `lanealignd`: the drift correction daemon.

use std::io::IsTerminal;
use std::path::PathBuf;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};
use lanealign_service::config::LogFormat;
use lanealign_service::{daemon, fail_stop};
use lanealign_wire::service::version_line;
use tracing_subscriber::EnvFilter;

#[derive(Parser)]
#[command(
    name = "lanealignd",
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

/// Log records waiting for stderr before newer ones are dropped (a few MB at most).
const LOG_LINES_BUFFERED: usize = 4096;

fn main() -> std::process::ExitCode {
    let version = version_line(env!("CARGO_PKG_VERSION"));
    let cli = Cli::from_arg_matches(&Cli::command().version(version).get_matches())
        .unwrap_or_else(|e| e.exit());
    lanealign_core::report::exit_code(run(cli))
}

fn run(cli: Cli) -> anyhow::Result<()> {
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    let Some(path) = cli.config else {
        anyhow::bail!("--config FILE is required");
    };
    let prepared = daemon::prepare(&path)?;
    let format = cli.log_format.unwrap_or(prepared.config.log_format);
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info"));
    // Records go to stderr from a thread of their own: a log nobody reads (a full pipe, a
    // stalled journald, a paused terminal) must never hold up a worker. When LOG_LINES_BUFFERED
    // wait, newer ones are dropped and counted; the guard flushes at exit, waiting 1.1 s at most.
    let (writer, flushed_at_exit) = tracing_appender::non_blocking::NonBlockingBuilder::default()
        .lossy(true)
        .buffered_lines_limit(LOG_LINES_BUFFERED)
        .thread_name("log")
        .finish(std::io::stderr());
    let dropped = writer.error_counter();
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(writer)
        .with_ansi(std::io::stderr().is_terminal());
    match format {
        LogFormat::Json => builder.json().init(),
        LogFormat::Text => builder.init(),
    }
    for warning in prepared.anchor_warnings() {
        tracing::warn!("{warning}");
    }
    match cli.command {
        Some(Command::Check) => {
            let _flushed_at_exit = flushed_at_exit;
            let latency = prepared
                .config
                .cpu_dma_latency_us
                .map_or(String::new(), |us| {
                    format!(
                        "; CPU wake-up latency {us} us asked of the kernel while the daemon runs"
                    )
                });
            let signed = prepared.tile.signer.map_or("unsigned".into(), |key| {
                format!("signed by {}", lanealign_core::tile::key_hex(&key))
            });
            let version = match prepared.served_map_version {
                Some(served) => {
                    format!("{}, newest served here {served}", prepared.tile.map_version)
                }
                None => prepared.tile.map_version.to_string(),
            };
            println!(
                "{}: ok: {} sources, namespace {}, {} {} ({} lanes, {} points; {}; {signed}; map version {version}){latency}",
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
            let _flushed_at_exit = fail_stop::abort_on_panic(flushed_at_exit);
            let summaries = daemon::run(prepared, move || dropped.dropped_lines() as u64)?;
            for (name, s) in summaries {
                tracing::info!(source = %name, received = s.received, published = s.published, "final");
            }
        }
    }
    Ok(())
}
