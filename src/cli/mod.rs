//! Subcommand implementations. Errors reach `main` as `anyhow` errors; an error that wraps
//! [`BadInput`] means the user gave something unusable and exits 2.

pub mod align;
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
pub mod track;

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

/// Who reads what the daemon commands (`run`, `replay`) print.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Console {
    /// A person at a terminal: each event as one human line on stdout, with the state lines
    /// (waiting, poses, rates); tracing shows only warnings that are no event.
    Human,
    /// The journal, a file or a pipe: each event as one structured tracing line on stderr;
    /// stdout keeps only the results (the pose table, the files written).
    Journal,
}

impl Console {
    /// Human when stdout and stderr are terminals and stderr is not the journal.
    pub fn detect() -> Console {
        use std::io::IsTerminal as _;
        Console::choose(
            stderr_is_journal(),
            std::io::stdout().is_terminal(),
            std::io::stderr().is_terminal(),
        )
    }

    fn choose(stderr_is_journal: bool, stdout_tty: bool, stderr_tty: bool) -> Console {
        if !stderr_is_journal && stdout_tty && stderr_tty {
            Console::Human
        } else {
            Console::Journal
        }
    }

    /// The log filter used when `RUST_LOG` is not set. For the daemon commands at a terminal
    /// the events (target `scanfuse::event`) and the driver's own lines about its link are
    /// left out: the console prints each of them once already, as a person's line.
    fn default_filter(self, daemon: bool) -> &'static str {
        match (self, daemon) {
            (Console::Human, true) => "warn,scanfuse::event=off,scanfuse::sensor::driver=error",
            (Console::Human, false) => "warn",
            // The in-process emulators of `replay:` sensors say nothing an operator needs.
            (Console::Journal, true) => "info,scanfuse::emulator=warn",
            (Console::Journal, false) => "info",
        }
    }
}

/// True when stderr is the stream systemd named in `JOURNAL_STREAM` (`DEV:INODE`); a shell
/// started from a service inherits the variable, so its value is checked against stderr.
fn stderr_is_journal() -> bool {
    use std::os::fd::AsFd as _;
    use std::os::unix::fs::MetadataExt as _;
    let Some(value) = std::env::var_os("JOURNAL_STREAM") else {
        return false;
    };
    let Some((dev, ino)) = value.to_str().and_then(|v| v.split_once(':')) else {
        return false;
    };
    let Ok(fd) = std::io::stderr().as_fd().try_clone_to_owned() else {
        return false;
    };
    std::fs::File::from(fd)
        .metadata()
        .is_ok_and(|m| dev.parse() == Ok(m.dev()) && ino.parse() == Ok(m.ino()))
}

/// Logs go to stderr, filtered by `RUST_LOG`. Without it: `info` for the journal and pipes,
/// `warn` at a terminal, where the subcommands print their own lines for a person; the daemon
/// commands (`daemon`) choose by [`Console::detect`] so that each event is printed once.
pub fn init_logging(daemon: bool) {
    use std::io::IsTerminal as _;
    let stderr_tty = std::io::stderr().is_terminal();
    let console = if daemon {
        Console::detect()
    } else {
        Console::choose(false, true, stderr_tty)
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(console.default_filter(daemon)));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(stderr_tty)
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_person_at_a_terminal_gets_the_human_lines_and_anything_else_the_structured_ones() {
        assert_eq!(Console::choose(false, true, true), Console::Human);
        assert_eq!(Console::choose(true, true, true), Console::Journal);
        assert_eq!(Console::choose(false, false, true), Console::Journal);
        assert_eq!(Console::choose(false, true, false), Console::Journal);
    }

    #[test]
    fn at_a_terminal_the_daemon_logs_no_event_the_console_prints() {
        let human = Console::Human.default_filter(true);
        assert!(human.contains("scanfuse::event=off"), "{human}");
        assert!(human.contains("scanfuse::sensor::driver=error"), "{human}");
        assert!(human.starts_with("warn"), "{human}");
        let journal = Console::Journal.default_filter(true);
        assert!(
            journal.starts_with("info") && !journal.contains("event"),
            "{journal}"
        );
        // Every filter parses.
        for console in [Console::Human, Console::Journal] {
            for daemon in [true, false] {
                let f = console.default_filter(daemon);
                assert!(tracing_subscriber::EnvFilter::try_new(f).is_ok(), "{f}");
            }
        }
    }
}
