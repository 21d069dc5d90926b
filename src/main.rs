//! The `scanfuse` command line. Each subcommand lives in `cli/<name>.rs`; this file only parses
//! and dispatches, and turns errors into exit codes (2 = bad input, 1 = anything else).

mod cli;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "scanfuse",
    version,
    about = "Fuse several Hokuyo laser scanners into one site frame"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Serve one sensor of a recording over TCP as a live SCIP 2.0 unit (tests, demos).
    Emulate(cli::emulate::Args),
    /// Describe a recording: sensors, models, PP fields, scan counts, rate, gaps, truth.
    Info(cli::info::Args),
    /// Record a live sensor (or `scanfuse emulate`) into an MCAP recording, raw SCIP included.
    Record(cli::record::Args),
    /// Simulate a floor plan with sensors and people into a recording with ground truth.
    Simulate(cli::simulate::Args),
    /// Work out every sensor's pose from the scans in the given recordings.
    Register(cli::register::Args),
    /// Align the registered site to a building drawing (DXF, SVG, PNG/PGM): building_from_site.
    Align(cli::align::Args),
    /// Measure registration: success per overlap bin, errors, time, baselines, real data.
    Eval(cli::eval::Args),
    /// Validate a site config without starting anything (exit 2 on a bad config).
    Check(cli::check::Args),
    /// Run the daemon in the foreground: drivers, registration, fused map, status socket.
    Run(cli::run::Args),
    /// Run the whole pipeline on recordings, with no config: poses and map files to a folder.
    Replay(cli::replay::Args),
    /// Ask the running daemon how its sensors and poses are (table, --json or --watch).
    Status(cli::status::Args),
    /// Track people in recordings: one TRACKS line (NDJSON) per fused step.
    Track(cli::track::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    cli::init_logging(matches!(cli.command, Command::Run(_) | Command::Replay(_)));
    let result = match cli.command {
        Command::Emulate(args) => cli::emulate::run(args),
        Command::Info(args) => cli::info::run(args),
        Command::Record(args) => cli::record::run(args),
        Command::Simulate(args) => cli::simulate::run(args),
        Command::Eval(args) => cli::eval::run(args),
        Command::Register(args) => cli::register::run(args),
        Command::Align(args) => cli::align::run(args),
        Command::Check(args) => cli::check::run(args),
        Command::Status(args) => cli::status::run(args),
        Command::Run(args) => cli::run::run(args),
        Command::Replay(args) => cli::replay::run(args),
        Command::Track(args) => cli::track::run(args),
    };
    cli::exit_code(result)
}
