//! The signals a service manager sends: SIGTERM (and Ctrl-C's SIGINT) to stop after saving,
//! SIGHUP to re-read the config.

use tokio::signal::unix::{Signal as UnixSignal, SignalKind, signal};

/// What was asked of the daemon.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Request {
    /// SIGTERM or SIGINT: save, then exit.
    Terminate,
    /// SIGHUP: re-read the config and apply what changed.
    Reload,
}

/// Installed handlers; from now on these signals no longer kill the process by default.
pub struct Signals {
    term: UnixSignal,
    int: UnixSignal,
    hup: UnixSignal,
}

impl Signals {
    /// Installs the handlers (inside a tokio runtime).
    pub fn install() -> std::io::Result<Signals> {
        Ok(Signals {
            term: signal(SignalKind::terminate())?,
            int: signal(SignalKind::interrupt())?,
            hup: signal(SignalKind::hangup())?,
        })
    }

    /// The next request. Signals of one kind that arrive together are delivered once.
    pub async fn next(&mut self) -> Request {
        tokio::select! {
            _ = self.term.recv() => Request::Terminate,
            _ = self.int.recv() => Request::Terminate,
            _ = self.hup.recv() => Request::Reload,
        }
    }
}
