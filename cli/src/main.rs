//! `lanealign`: correct a recorded odometry run against lanes, evaluate trajectories, and talk
//! to `lanealignd` (replay, soak, demo).

mod commands;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};
use lanealign_wire::service::version_line;

#[derive(Parser)]
#[command(
    name = "lanealign",
    about = "Odometry drift correction against OpenStreetMap lanes (docs/algorithm.md)"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Correct a recorded trajectory offline.
    Correct(commands::correct::CorrectArgs),
    /// APE-2D of an estimate against ground truth (no alignment).
    Eval(commands::eval::EvalArgs),
    /// Print the effective corrector parameters of a preset, method and overrides as TOML.
    Params(commands::params::ParamsArgs),
    /// Stream a trajectory through a running lanealignd and write the corrected one.
    Replay(commands::replay::ReplayArgs),
    /// Many sources through a daemon it starts itself: latency and loss, with correction and in
    /// pass-through, for each wait strategy; the phases run one after another.
    Soak(commands::soak::SoakArgs),
    /// Compile a map, start lanealignd, replay an odometry run through it, print the result.
    Demo,
}

fn main() -> std::process::ExitCode {
    let version = version_line(env!("CARGO_PKG_VERSION"));
    let cli = Cli::from_arg_matches(&Cli::command().version(version).get_matches())
        .unwrap_or_else(|e| e.exit());
    // The commands that only read files and print end like Unix filters when their reader goes
    // away; the ones that talk to a daemon keep Rust's handling, so that a daemon gone mid-stream
    // is an error they report rather than a signal.
    if matches!(
        cli.command,
        Command::Correct(_) | Command::Eval(_) | Command::Params(_)
    ) {
        lanealign_core::report::end_quietly_on_closed_pipe();
    }
    // iceoryx2 warns on stdout when it runs on its default configuration, which is intended here.
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    lanealign_core::report::exit_code(run(&cli))
}

fn run(cli: &Cli) -> anyhow::Result<()> {
    match &cli.command {
        Command::Correct(args) => commands::correct::run(args),
        Command::Eval(args) => commands::eval::run(args),
        Command::Params(args) => commands::params::run(args),
        Command::Replay(args) => commands::replay::run(args),
        Command::Soak(args) => commands::soak::run(args),
        Command::Demo => commands::demo::run(),
    }
}
