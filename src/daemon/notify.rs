//! Talking to systemd (`Type=notify`): READY=1 once the config is loaded and the socket bound,
//! STATUS= lines a person sees in `systemctl status`, WATCHDOG=1 while the pipeline is alive.
//! Without `NOTIFY_SOCKET` (not started by systemd) every call is a no-op.

use std::time::Duration;

use sd_notify::NotifyState;

/// A notification could not be delivered.
#[derive(Debug, thiserror::Error)]
#[error("cannot notify systemd: {0}")]
pub struct NotifyError(#[from] std::io::Error);

/// The daemon's side of the systemd notification protocol.
#[derive(Debug, Clone, Copy)]
pub struct Notifier {
    /// Half the service's `WatchdogSec`, when systemd asked for pings.
    watchdog_interval: Option<Duration>,
}

impl Notifier {
    /// Reads `WATCHDOG_USEC`/`WATCHDOG_PID` once; `NOTIFY_SOCKET` is read at each send.
    pub fn from_env() -> Notifier {
        Notifier {
            watchdog_interval: sd_notify::watchdog_enabled().map(|d| d / 2),
        }
    }

    /// How often to send WATCHDOG=1, if systemd wants it: half of `WatchdogSec`, as
    /// `sd_watchdog_enabled(3)` recommends.
    pub fn watchdog_interval(&self) -> Option<Duration> {
        self.watchdog_interval
    }

    /// READY=1 with a first status line.
    pub fn ready(&self, status: &str) -> Result<(), NotifyError> {
        Ok(sd_notify::notify(&[
            NotifyState::Ready,
            NotifyState::Status(status),
        ])?)
    }

    /// A STATUS= line, e.g. "4/4 sensors, registered".
    pub fn status(&self, status: &str) -> Result<(), NotifyError> {
        Ok(sd_notify::notify(&[NotifyState::Status(status)])?)
    }

    /// WATCHDOG=1: the pipeline is alive.
    pub fn watchdog(&self) -> Result<(), NotifyError> {
        Ok(sd_notify::notify(&[NotifyState::Watchdog])?)
    }

    /// RELOADING=1 (with the MONOTONIC_USEC systemd ≥ 253 requires), before a SIGHUP reload;
    /// follow with [`Notifier::ready`].
    pub fn reloading(&self) -> Result<(), NotifyError> {
        let now = NotifyState::monotonic_usec_now()?;
        Ok(sd_notify::notify(&[NotifyState::Reloading, now])?)
    }

    /// STOPPING=1 at the start of a clean shutdown.
    pub fn stopping(&self) -> Result<(), NotifyError> {
        Ok(sd_notify::notify(&[NotifyState::Stopping])?)
    }

    /// Pings the watchdog every [`Notifier::watchdog_interval`] while `alive()` holds, until
    /// `shutdown` resolves. A dead pipeline stops the pings, so systemd restarts the service.
    /// Returns at once when systemd asked for no watchdog.
    pub async fn run_watchdog(
        self,
        alive: impl Fn() -> bool,
        shutdown: impl std::future::Future<Output = ()>,
    ) {
        let Some(interval) = self.watchdog_interval else {
            return;
        };
        let mut ticker = tokio::time::interval(interval);
        ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        tokio::pin!(shutdown);
        loop {
            tokio::select! {
                _ = &mut shutdown => return,
                _ = ticker.tick() => {
                    if alive() && let Err(e) = self.watchdog() {
                        tracing::warn!("{e}");
                    }
                }
            }
        }
    }
}
