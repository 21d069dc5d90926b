//! Talking to systemd (`Type=notify`): READY=1 once the config is loaded and the socket bound,
//! STATUS= lines a person sees in `systemctl status`, WATCHDOG=1 while the pipeline is alive.
//! Without `NOTIFY_SOCKET` (not started by systemd) every call is a no-op.

use std::time::Duration;

use sd_notify::NotifyState;

use super::protocol::{Poses, SensorState, Status};

/// The one-line summary systemd shows (`systemctl status`), e.g.
/// "4/4 sensors streaming, registered" or "3/4 sensors streaming, 2/4 registered".
pub fn status_line(status: &Status, poses: &Poses) -> String {
    let total = status.sensors.len();
    let streaming = status
        .sensors
        .iter()
        .filter(|s| s.state == SensorState::Streaming)
        .count();
    let registered = poses.sensors.iter().filter(|p| p.registered).count();
    if registered == total {
        format!("{streaming}/{total} sensors streaming, registered")
    } else {
        format!("{streaming}/{total} sensors streaming, {registered}/{total} registered")
    }
}

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::daemon::protocol::{SensorPose, SensorStatus};

    #[test]
    fn the_status_line_counts_streaming_and_registered_sensors() {
        let mut status = Status {
            site: "s".into(),
            uptime_s: 0.0,
            queue_drops: 0,
            sensors: vec![
                SensorStatus::new("a", SensorState::Streaming),
                SensorStatus::new("b", SensorState::Disconnected),
            ],
            web: None,
            foxglove: None,
            zenoh: None,
            zones: Vec::new(),
        };
        let mut a = SensorPose::unregistered("a", "");
        a.registered = true;
        let mut poses = Poses {
            anchor: "a".into(),
            sensors: vec![a.clone(), SensorPose::unregistered("b", "no view")],
            building_from_site: None,
            site_from_zone: None,
        };
        assert_eq!(
            status_line(&status, &poses),
            "1/2 sensors streaming, 1/2 registered"
        );
        status.sensors[1].state = SensorState::Streaming;
        poses.sensors[1] = SensorPose {
            id: "b".into(),
            ..a
        };
        assert_eq!(
            status_line(&status, &poses),
            "2/2 sensors streaming, registered"
        );
    }
}
