//! Subcommand implementations. Errors reach `main` as `anyhow` errors; an error that wraps
//! [`BadInput`] means the user gave something unusable and exits 2.

pub mod check;
pub mod emulate;
pub mod eval;
pub mod info;
pub mod record;
pub mod register;
pub mod replay;
pub mod run;
pub mod simulate;
pub mod status;

use std::process::ExitCode;

/// Marks an error as the user's input being unusable (exit code 2), not a failure of ours.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct BadInput(pub String);

/// Stdout's reader went away (`scanfuse status --watch | head -5`): the command stops and
/// exits 0 without a word, as command-line tools do.
#[derive(Debug, thiserror::Error)]
#[error("stdout was closed by its reader")]
pub struct StdoutClosed;

/// The error for a failed write to stdout: [`StdoutClosed`] for a closed pipe, else the
/// write error itself.
pub fn stdout_error(e: std::io::Error) -> anyhow::Error {
    if e.kind() == std::io::ErrorKind::BrokenPipe {
        StdoutClosed.into()
    } else {
        anyhow::Error::new(e).context("cannot write to stdout")
    }
}

/// Logs go to stderr, filtered by `RUST_LOG`. The default is `info` for the journal and pipes,
/// `warn` at a terminal, where the subcommands print their own lines for a person.
pub fn init_logging() {
    use std::io::IsTerminal as _;
    let default = if std::io::stderr().is_terminal() {
        "warn"
    } else {
        "info"
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .init();
}

/// Prints the error chain once and maps it to an exit code.
pub fn exit_code(result: anyhow::Result<()>) -> ExitCode {
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) if err.chain().any(|e| e.is::<StdoutClosed>()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            if err.chain().any(|e| e.is::<BadInput>()) || is_input_error(&err) {
                ExitCode::from(2)
            } else {
                ExitCode::FAILURE
            }
        }
    }
}

/// Errors from reading the user's files count as bad input.
fn is_input_error(err: &anyhow::Error) -> bool {
    err.chain()
        .any(|e| e.is::<scanfuse::record::RecordError>() || e.is::<scanfuse::sim::PlanError>())
}
