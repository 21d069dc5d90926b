//! The driver state machine: connect → handshake (QT RS VV PP II) → TM sync → start the
//! stream → stream → (silence or error) → back off → reconnect. It never panics on what the
//! sensor sends; every failure is counted and the last one kept as text.
//!
//! It gives up on a sensor (a [`DriverEvent::Failed`], then the task ends) only when retrying
//! cannot help and a person must act: the unit answers the configured mode's scan command with
//! "undefined command" (e.g. ND on a unit without multi-echo), or it stays in its abnormal
//! state (`0L`) through [`MAX_REBOOTS`] reboots.
//!
//! Known UTM-30LX-EW habits it tolerates: TM0 fails while the unit boots (retried), QT also
//! ends time-adjust mode (used as the fallback when TM2 fails), II says `Measuring` after QT
//! (II is read for the record, never trusted for state). A unit in its abnormal state answers
//! `0L`; as the reference drivers do, after [`ABNORMAL_SESSIONS_BEFORE_REBOOT`] connections
//! ending that way it is rebooted (RB twice within a second, as SCIP 2.0 requires).

use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use thiserror::Error;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;

use super::clock::{ClockModel, TimeSample, Unwrapper, sync};
use super::counters::Counters;
use super::transport::{Link, TransportError, connect};
use crate::scan::{Scan, ScanGeometry, SensorInfo};
use crate::scip::command::{Command, DataKind, Request, ScanRequest, TimeControl};
use crate::scip::info::{Parameters, StateInfo, VersionInfo, parse_tm1};
use crate::scip::scan::{Echo, ScanError, ScipScan};
use crate::scip::status::{StatusError, StatusKind};
use crate::scip::{Frame, Framer, Reply};

/// Connections in a row ending in `0L` (abnormal state) before the driver reboots the unit.
pub const ABNORMAL_SESSIONS_BEFORE_REBOOT: u32 = 3;
/// Reboots without a scan in between before the driver gives up on a unit in its abnormal
/// state and reports it failed. A unit that streams again starts the count afresh.
pub const MAX_REBOOTS: u32 = 2;

/// Shortest no-data watchdog, whatever the scan rate.
const MIN_WATCHDOG: Duration = Duration::from_millis(50);
/// On shutdown: how long to wait for the answer to QT (laser off) and for the link to close.
/// A unit that does not answer in time is left as it is; shutdown never hangs on a sensor.
pub const QUIT_TIMEOUT: Duration = Duration::from_millis(500);

/// Which stream to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ScanMode {
    /// Ranges.
    Md,
    /// Ranges and intensities.
    Me,
    /// Multi-echo ranges.
    Nd,
    /// Multi-echo ranges and intensities.
    Ne,
}

impl ScanMode {
    pub fn kind(self) -> DataKind {
        match self {
            ScanMode::Md => DataKind::Range,
            ScanMode::Me => DataKind::RangeIntensity,
            ScanMode::Nd => DataKind::MultiRange,
            ScanMode::Ne => DataKind::MultiRangeIntensity,
        }
    }

    /// The command's two letters, as in the config.
    pub fn as_str(self) -> &'static str {
        match self {
            ScanMode::Md => "MD",
            ScanMode::Me => "ME",
            ScanMode::Nd => "ND",
            ScanMode::Ne => "NE",
        }
    }

    pub fn parse(text: &str) -> Option<ScanMode> {
        match text.to_ascii_uppercase().as_str() {
            "MD" => Some(ScanMode::Md),
            "ME" => Some(ScanMode::Me),
            "ND" => Some(ScanMode::Nd),
            "NE" => Some(ScanMode::Ne),
            _ => None,
        }
    }
}

/// How long to wait for what. Named here, not scattered through the code.
#[derive(Debug, Clone)]
pub struct DriverConfig {
    pub id: String,
    /// `tcp://host:port` or `serial:///dev/…`.
    pub connect: String,
    pub mode: ScanMode,
    pub connect_timeout: Duration,
    /// For the answer to one command.
    pub reply_timeout: Duration,
    /// Silence, in scan periods, after which the link is declared dead.
    pub watchdog_periods: f64,
    pub backoff_initial: Duration,
    pub backoff_max: Duration,
    /// TM1 exchanges per sync.
    pub sync_samples: usize,
    /// TM0 attempts while the unit boots.
    pub tm0_attempts: u32,
    /// Also send every chunk of bytes read, for `/<id>/scip`.
    pub raw: bool,
}

impl DriverConfig {
    pub fn new(id: impl Into<String>, connect: impl Into<String>) -> Self {
        DriverConfig {
            id: id.into(),
            connect: connect.into(),
            mode: ScanMode::Me,
            connect_timeout: Duration::from_secs(3),
            reply_timeout: Duration::from_secs(2),
            watchdog_periods: 3.0,
            backoff_initial: Duration::from_millis(100),
            backoff_max: Duration::from_secs(10),
            sync_samples: 10,
            tm0_attempts: 5,
            raw: false,
        }
    }
}

/// A scan plus what `scan::Scan` does not carry.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorScan {
    /// `stamp_ns` is the host receive time, `sensor_stamp_ms` the unwrapped sensor clock.
    pub scan: Scan,
    /// When the sensor measured it, on the host clock (TM1 sync plus drift), ns since the epoch.
    pub measured_ns: Option<u64>,
    /// Second and third echoes (ND/NE only), ranges in mm as sent.
    pub extra_echoes: Vec<Echo>,
}

#[derive(Debug, Clone, PartialEq)]
pub enum DriverEvent {
    /// Handshake done: the sensor's identity and every VV/PP/II field.
    Connected(SensorInfo),
    Scan(SensorScan),
    /// Bytes as read from the link (only with `raw`).
    Raw {
        stamp_ns: u64,
        bytes: Vec<u8>,
    },
    Disconnected {
        reason: String,
    },
    /// The driver gave up on the sensor: retrying cannot help (a mode it does not have, a
    /// fault reboots did not clear). `reason` says what a person should do. The task ends.
    Failed {
        reason: String,
    },
}

#[derive(Debug, Error)]
#[non_exhaustive]
pub enum DriverError {
    #[error(transparent)]
    Transport(#[from] TransportError),
    #[error("link: {0}")]
    Io(#[from] std::io::Error),
    #[error("sensor closed the connection")]
    Closed,
    #[error("no answer to {0} within {1:?}")]
    NoReply(String, Duration),
    #[error("no scan for {} (watchdog)", crate::human::duration(*.0))]
    NoData(Duration),
    #[error(transparent)]
    Status(#[from] StatusError),
    #[error("{what}: {why}")]
    BadReply { what: &'static str, why: String },
    #[error("the sensor's clock could not be read (no valid TM1 answer)")]
    NoTimeSync,
    #[error("the unit is still booting (it refused TM0 {attempts} times, with {}); retrying", .refusal.status_text())]
    StillBooting { attempts: u32, refusal: StatusError },
    #[error("{}", silent(.uri, *.serial, .timeout))]
    NotAnswering {
        uri: String,
        serial: bool,
        timeout: Duration,
    },
    #[error("this {model} answers {} to {}: {}", String::from_utf8_lossy(.code), .mode.as_str(), unsupported_advice(*.mode))]
    UnsupportedMode {
        model: String,
        mode: ScanMode,
        code: [u8; 2],
    },
    #[error(
        "{last}, still after {reboots} reboots: power-cycle the unit and check it (its LED, the manual's error list); scanfuse stopped retrying it"
    )]
    AbnormalAfterReboots { reboots: u32, last: StatusError },
    #[error("shutting down")]
    Shutdown,
}

/// What to do about a unit that answers `mode`'s scan command "undefined command".
fn unsupported_advice(mode: ScanMode) -> &'static str {
    match mode {
        ScanMode::Nd | ScanMode::Ne => "it has no multi-echo mode; use MD or ME",
        ScanMode::Me => "it sends no intensities; use MD",
        ScanMode::Md => "it does not stream ranges; check that it is a SCIP 2.0 unit",
    }
}

/// Why a link that opened may stay silent. Over TCP the unit (or something) accepted the
/// connection, so it is powered: the likely cause is another client holding it.
fn silent(uri: &str, serial: bool, timeout: &Duration) -> String {
    if serial {
        format!(
            "no answer to QT within {timeout:?} on {uri}: the unit may be unpowered, not a SCIP 2.0 unit or at another baud rate, or another program holds the port"
        )
    } else {
        format!(
            "{uri} accepted the connection but sent no answer to QT within {timeout:?}: another client may hold the unit (Hokuyo units serve one client at a time), or it is not a SCIP 2.0 unit"
        )
    }
}

/// Host time as ns since the epoch, advancing with tokio's clock (so paused tests control it).
#[derive(Debug, Clone, Copy)]
struct HostClock {
    epoch_ns: u64,
    base: Instant,
}

impl HostClock {
    fn new() -> Self {
        let epoch_ns = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as u64);
        HostClock {
            epoch_ns,
            base: Instant::now(),
        }
    }
    fn now_ns(&self) -> u64 {
        self.epoch_ns + self.base.elapsed().as_nanos() as u64
    }
}

/// One sensor's driver.
pub struct Driver {
    config: DriverConfig,
    counters: Arc<Counters>,
    host: HostClock,
    connector: Option<Connector>,
}

/// Opens a link; replaces [`connect`] for in-process tests.
pub type Connector = Arc<
    dyn Fn() -> Pin<Box<dyn Future<Output = Result<Link, TransportError>> + Send>> + Send + Sync,
>;

impl Driver {
    pub fn new(config: DriverConfig) -> Self {
        Driver {
            config,
            counters: Arc::new(Counters::default()),
            host: HostClock::new(),
            connector: None,
        }
    }

    /// A driver that opens its links with `connector` instead of `config.connect`.
    pub fn with_connector(config: DriverConfig, connector: Connector) -> Self {
        Driver {
            connector: Some(connector),
            ..Driver::new(config)
        }
    }

    pub fn counters(&self) -> Arc<Counters> {
        self.counters.clone()
    }

    /// Runs until `shutdown` turns true or `events` is closed.
    pub async fn run(self, events: mpsc::Sender<DriverEvent>, mut shutdown: watch::Receiver<bool>) {
        let mut backoff = self.config.backoff_initial;
        let mut first = true;
        // Connections in a row that ended in `0L`, and reboots since the last scan.
        let mut abnormal_sessions = 0u32;
        let mut reboots = 0u32;
        loop {
            if *shutdown.borrow() || events.is_closed() {
                return;
            }
            if !first {
                Counters::add(&self.counters.reconnects, 1);
            }
            first = false;
            let mut session = Session::new(&self, &events);
            let result = tokio::select! {
                r = session.run() => r,
                _ = shutdown.wait_for(|s| *s) => Err(DriverError::Shutdown),
            };
            let delivered = session.delivered > 0;
            let error = match result {
                Err(DriverError::Shutdown) => {
                    session.quit(QUIT_TIMEOUT).await;
                    return;
                }
                Err(e) => e,
                Ok(()) => DriverError::Closed,
            };
            if delivered {
                reboots = 0;
            }
            let mut fatal = matches!(error, DriverError::UnsupportedMode { .. });
            let error = match error {
                DriverError::Status(last) if last.kind == StatusKind::Abnormal => {
                    abnormal_sessions += 1;
                    if abnormal_sessions < ABNORMAL_SESSIONS_BEFORE_REBOOT {
                        DriverError::Status(last)
                    } else if reboots >= MAX_REBOOTS {
                        fatal = true;
                        DriverError::AbnormalAfterReboots { reboots, last }
                    } else {
                        abnormal_sessions = 0;
                        reboots += 1;
                        tracing::warn!(sensor = %self.config.id, error = %last, reboot = reboots, max_reboots = MAX_REBOOTS, "sensor in its abnormal state; rebooting it (RB twice)");
                        let rebooted = tokio::select! {
                            r = session.reboot() => r,
                            _ = shutdown.wait_for(|s| *s) => return,
                        };
                        match rebooted {
                            Ok(()) => {
                                tracing::info!(sensor = %self.config.id, "reboot accepted; reconnecting")
                            }
                            Err(e) => {
                                tracing::warn!(sensor = %self.config.id, error = %e, "reboot not accepted")
                            }
                        }
                        DriverError::Status(last)
                    }
                }
                other => {
                    abnormal_sessions = 0;
                    other
                }
            };
            self.counters.set_last_error(error.to_string());
            if fatal {
                tracing::error!(sensor = %self.config.id, error = %error, "sensor failed; not retrying");
                session.quit(QUIT_TIMEOUT).await;
                let failed = DriverEvent::Failed {
                    reason: error.to_string(),
                };
                tokio::select! {
                    _ = events.send(failed) => {}
                    _ = shutdown.wait_for(|s| *s) => {}
                }
                return;
            }
            if matches!(error, DriverError::StillBooting { .. }) {
                tracing::warn!(sensor = %self.config.id, error = %error, "sensor still booting; reconnecting");
            } else {
                tracing::warn!(sensor = %self.config.id, error = %error, "sensor link lost; reconnecting");
            }
            let _ = events.try_send(DriverEvent::Disconnected {
                reason: error.to_string(),
            });
            if delivered {
                backoff = self.config.backoff_initial;
            }
            tokio::select! {
                _ = tokio::time::sleep(backoff) => {}
                _ = shutdown.wait_for(|s| *s) => return,
            }
            backoff = (backoff * 2).min(self.config.backoff_max);
        }
    }
}

/// One connection's worth of state.
struct Session<'a> {
    driver: &'a Driver,
    events: &'a mpsc::Sender<DriverEvent>,
    link: Option<Link>,
    framer: Framer,
    skipped_seen: u64,
    scratch: Vec<u8>,
    read_buf: Vec<u8>,
    delivered: u64,
    tm1_tag: u32,
}

impl<'a> Session<'a> {
    fn new(driver: &'a Driver, events: &'a mpsc::Sender<DriverEvent>) -> Self {
        Session {
            driver,
            events,
            link: None,
            framer: Framer::new(),
            skipped_seen: 0,
            scratch: Vec::new(),
            read_buf: vec![0; 16 * 1024],
            delivered: 0,
            tm1_tag: 0,
        }
    }

    async fn run(&mut self) -> Result<(), DriverError> {
        let config = &self.driver.config;
        let opened = match &self.driver.connector {
            Some(connector) => connector().await,
            None => connect(&config.connect, config.connect_timeout).await,
        };
        match opened {
            Ok(link) => self.link = Some(link),
            Err(e) => {
                Counters::add(&self.driver.counters.connect_failures, 1);
                return Err(e.into());
            }
        }
        let (info, geometry) = self.handshake().await?;
        let clock = self.time_sync().await?;
        // Started before the sensor is reported connected: a mode the unit does not have is
        // found here, and the sensor is never reported as streaming it.
        let symbol = self.start_stream(&geometry, &info.model).await?;
        Counters::add(&self.driver.counters.connects, 1);
        tracing::info!(sensor = %config.id, model = %info.model, "sensor connected");
        let _ = self.events.send(DriverEvent::Connected(info)).await;
        self.stream(geometry, clock, symbol).await
    }

    /// Reboots a unit in its abnormal state: RB twice within a second (SCIP 2.0: the first is
    /// answered `01`, the second `00`, then the unit restarts and drops the link). The link is
    /// closed afterwards whatever the unit did.
    async fn reboot(&mut self) -> Result<(), DriverError> {
        let request = Request::new(Command::Reboot);
        let outcome = async {
            self.command(&request).await?;
            match self.command(&request).await {
                Ok(frame) => {
                    let reply = parse_reply(&frame, "RB")?;
                    reply.status.check(*b"RB")?;
                    Ok(())
                }
                // A unit may restart before its answer gets out.
                Err(DriverError::Closed | DriverError::Io(_) | DriverError::NoReply(..)) => Ok(()),
                Err(e) => Err(e),
            }
        }
        .await;
        if let Some(mut link) = self.link.take() {
            let _ = tokio::time::timeout(QUIT_TIMEOUT, link.shutdown()).await;
        }
        outcome
    }

    fn counters(&self) -> &Counters {
        &self.driver.counters
    }

    /// Stops the laser (QT) and closes the link, waiting at most `bound` in all. Does nothing
    /// when no link is open. A stream still running sends scans until the unit reads the QT;
    /// they are passed over.
    async fn quit(&mut self, bound: Duration) {
        if self.link.is_none() {
            return;
        }
        let deadline = Instant::now() + bound;
        let request = Request::new(Command::Quit);
        let answered = tokio::time::timeout_at(deadline, self.command(&request)).await;
        let id = &self.driver.config.id;
        match answered {
            Ok(Ok(_)) => tracing::debug!(sensor = %id, "laser stopped (QT answered)"),
            Ok(Err(e)) => tracing::debug!(sensor = %id, error = %e, "QT on shutdown failed"),
            Err(_) => tracing::debug!(sensor = %id, ?bound, "QT on shutdown not answered in time"),
        }
        if let Some(mut link) = self.link.take() {
            let _ = tokio::time::timeout_at(deadline, link.shutdown()).await;
        }
    }

    async fn send(&mut self, request: &Request) -> Result<(), DriverError> {
        let link = self.link.as_mut().ok_or(DriverError::Closed)?;
        link.write_all(&request.encode()).await?;
        Ok(())
    }

    /// The next frame, reading until `deadline`.
    async fn frame(&mut self, deadline: Instant) -> Result<Option<Frame>, DriverError> {
        loop {
            if let Some(frame) = self.framer.next_frame() {
                self.note_skipped();
                return Ok(Some(frame));
            }
            let link = self.link.as_mut().ok_or(DriverError::Closed)?;
            let n = match tokio::time::timeout_at(deadline, link.read(&mut self.read_buf)).await {
                Err(_) => return Ok(None),
                Ok(n) => n?,
            };
            if n == 0 {
                self.note_skipped();
                return Err(DriverError::Closed);
            }
            let bytes = self.read_buf.get(..n).unwrap_or_default();
            if self.driver.config.raw {
                // Raw bytes are for recordings, which must be complete: wait for the consumer.
                let event = DriverEvent::Raw {
                    stamp_ns: self.driver.host.now_ns(),
                    bytes: bytes.to_vec(),
                };
                self.events
                    .send(event)
                    .await
                    .map_err(|_| DriverError::Shutdown)?;
            }
            self.framer.push(bytes);
            self.note_skipped();
        }
    }

    fn note_skipped(&mut self) {
        let skipped = self.framer.stats().skipped_bytes;
        Counters::add(
            &self.driver.counters.skipped_bytes,
            skipped - self.skipped_seen,
        );
        self.skipped_seen = skipped;
    }

    /// Sends `request` and waits for the reply echoing it; other replies (scans still in
    /// flight, answers to earlier commands) are passed over.
    async fn command(&mut self, request: &Request) -> Result<Frame, DriverError> {
        self.send(request).await?;
        let line = request.line();
        let timeout = self.driver.config.reply_timeout;
        let deadline = Instant::now() + timeout;
        loop {
            match self.frame(deadline).await? {
                Some(frame) if frame.echo() == line.as_slice() => return Ok(frame),
                Some(_) => continue,
                None => {
                    return Err(DriverError::NoReply(
                        String::from_utf8_lossy(&line).into_owned(),
                        timeout,
                    ));
                }
            }
        }
    }

    /// Sends `request`, returns its parsed reply after checking the status.
    async fn checked(&mut self, command: Command) -> Result<Frame, DriverError> {
        let request = Request::new(command);
        let frame = self.command(&request).await?;
        let reply = parse_reply(&frame, "reply")?;
        reply.status.check(reply.symbol())?;
        Ok(frame)
    }

    async fn handshake(&mut self) -> Result<(SensorInfo, ScanGeometry), DriverError> {
        // QT stops a stream left running by an earlier client; RS puts settings back.
        match self.checked(Command::Quit).await {
            Err(DriverError::NoReply(_, timeout)) => {
                return Err(DriverError::NotAnswering {
                    uri: self.driver.config.connect.clone(),
                    serial: matches!(self.link, Some(Link::Serial(_))),
                    timeout,
                });
            }
            answered => answered?,
        };
        self.checked(Command::Reset).await?;
        let vv = self.checked(Command::Version).await?;
        let version =
            VersionInfo::parse(&parse_reply(&vv, "VV")?).map_err(|e| bad_info("VV", e))?;
        let pp = self.checked(Command::Parameters).await?;
        let params = Parameters::parse(&parse_reply(&pp, "PP")?).map_err(|e| bad_info("PP", e))?;
        let ii = self.checked(Command::Info).await?;
        // II is informative only: firmwares report "Measuring" after QT.
        let state = StateInfo::parse(&parse_reply(&ii, "II")?).ok();
        let config = &self.driver.config;
        let mut info = SensorInfo::new(config.id.clone(), params.model.clone());
        info.connect = config.connect.clone();
        info.geometry = Some(params.geometry);
        info.fields.extend(version.fields);
        if let Some(state) = state {
            info.fields.extend(state.fields);
        }
        info.fields.extend(params.fields);
        Ok((info, params.geometry))
    }

    /// TM0, TM1 × n, TM2 → clock offset.
    async fn time_sync(&mut self) -> Result<ClockModel, DriverError> {
        let attempts = self.driver.config.tm0_attempts.max(1);
        let mut entered = false;
        let mut refusal = None;
        for attempt in 1..=attempts {
            match self.checked(Command::Time(TimeControl::Enter)).await {
                Ok(_) => {
                    entered = true;
                    break;
                }
                // Already in time-adjust mode: fine.
                Err(DriverError::Status(e)) if &e.code == b"02" => {
                    entered = true;
                    break;
                }
                Err(DriverError::Status(e)) if e.kind != StatusKind::Abnormal => {
                    tracing::debug!(sensor = %self.driver.config.id, attempt, code = %String::from_utf8_lossy(&e.code), "TM0 refused; the unit may still be booting");
                    self.counters()
                        .set_last_error(format!("{e}; the unit may still be booting"));
                    refusal = Some(e);
                    tokio::time::sleep(Duration::from_millis(100 * attempt as u64)).await;
                }
                Err(e) => return Err(e),
            }
        }
        if !entered {
            return Err(match refusal {
                Some(refusal) => DriverError::StillBooting { attempts, refusal },
                None => DriverError::NoTimeSync,
            });
        }
        let mut samples = Vec::with_capacity(self.driver.config.sync_samples);
        for _ in 0..self.driver.config.sync_samples.max(1) {
            self.tm1_tag = self.tm1_tag.wrapping_add(1);
            // A tag per TM1 so a late answer to an earlier one cannot be taken for this one.
            let request = Request::tagged(
                Command::Time(TimeControl::Read),
                format!("s{}", self.tm1_tag),
            );
            let sent_ns = self.driver.host.now_ns();
            let frame = self.command(&request).await?;
            let received_ns = self.driver.host.now_ns();
            if let Some(sensor_ms) = Reply::parse(&frame)
                .ok()
                .filter(|r| r.status.is_success())
                .and_then(|r| parse_tm1(&r))
            {
                samples.push(TimeSample {
                    sent_ns,
                    received_ns,
                    sensor_ms,
                });
            }
        }
        if self
            .checked(Command::Time(TimeControl::Leave))
            .await
            .is_err()
        {
            // QT also ends time-adjust mode on the UTM-30LX-EW.
            self.checked(Command::Quit).await?;
        }
        let result = sync(&samples).ok_or(DriverError::NoTimeSync)?;
        Counters::add(&self.driver.counters.time_syncs, 1);
        let reference_ms = samples.last().map_or(0, |s| s.sensor_ms as u64);
        Ok(ClockModel::new(result, reference_ms))
    }

    /// Sends the configured mode's scan command; returns the symbol its blocks echo. A unit
    /// that does not know the command is [`DriverError::UnsupportedMode`].
    async fn start_stream(
        &mut self,
        geometry: &ScanGeometry,
        model: &str,
    ) -> Result<[u8; 2], DriverError> {
        let mode = self.driver.config.mode;
        let request = ScanRequest {
            kind: mode.kind(),
            continuous: true,
            start_step: geometry.amin as u16,
            end_step: geometry.amax as u16,
            cluster: 1,
            interval: 0,
            scans: 0,
        };
        match self.checked(Command::Scan(request)).await {
            Ok(_) => Ok(request.kind.symbol(true)),
            Err(DriverError::Status(e)) if e.kind == StatusKind::UndefinedCommand => {
                // PP's MODL often ends in the maker: "UTM-30LX(Hokuyo Automatic Co.,Ltd.)".
                let model = model.split('(').next().unwrap_or(model).trim();
                Err(DriverError::UnsupportedMode {
                    model: model.to_string(),
                    mode,
                    code: e.code,
                })
            }
            Err(e) => Err(e),
        }
    }

    async fn stream(
        &mut self,
        geometry: ScanGeometry,
        mut clock: ClockModel,
        symbol: [u8; 2],
    ) -> Result<(), DriverError> {
        let config = &self.driver.config;
        let watchdog = Duration::try_from_secs_f64(geometry.period_s() * config.watchdog_periods)
            .unwrap_or(Duration::ZERO)
            .max(MIN_WATCHDOG);
        let mut unwrapper = Unwrapper::default();
        let mut last_stamp_ns = 0u64;
        loop {
            let deadline = Instant::now() + watchdog;
            let frame = match self.frame(deadline).await? {
                Some(frame) => frame,
                None => {
                    Counters::add(&self.counters().watchdog_timeouts, 1);
                    return Err(DriverError::NoData(watchdog));
                }
            };
            let received_ns = self.driver.host.now_ns().max(last_stamp_ns + 1);
            if !frame.echo().starts_with(&symbol) {
                continue;
            }
            let reply = match Reply::parse(&frame) {
                Ok(reply) => reply,
                Err(_) => {
                    Counters::add(&self.counters().decode_errors, 1);
                    continue;
                }
            };
            let scan = match ScipScan::decode(&reply, &mut self.scratch) {
                Ok(scan) => scan,
                Err(ScanError::Acknowledgement) => continue,
                Err(ScanError::Checksum { line }) => {
                    Counters::add(&self.counters().checksum_errors, 1);
                    tracing::debug!(sensor = %config.id, line, "scan dropped: bad checksum");
                    continue;
                }
                Err(ScanError::Status(e)) if e.kind == StatusKind::Abnormal => {
                    Counters::add(&self.counters().status_errors, 1);
                    return Err(e.into());
                }
                Err(ScanError::Status(e)) => {
                    Counters::add(&self.counters().status_errors, 1);
                    self.counters().set_last_error(e.to_string());
                    continue;
                }
                Err(e) => {
                    Counters::add(&self.counters().decode_errors, 1);
                    self.counters().set_last_error(format!("scan dropped: {e}"));
                    continue;
                }
            };
            let sensor_ms = unwrapper.unwrap(scan.timestamp_ms);
            clock.observe(sensor_ms, received_ns);
            let measured_ns = u64::try_from(clock.host_ns(sensor_ms)).ok();
            last_stamp_ns = received_ns;
            let out = SensorScan {
                scan: scan.to_scan(&geometry, received_ns, Some(sensor_ms)),
                measured_ns,
                extra_echoes: scan.extra_echoes,
            };
            Counters::add(&self.counters().scans, 1);
            self.delivered += 1;
            if let Err(mpsc::error::TrySendError::Full(_)) =
                self.events.try_send(DriverEvent::Scan(out))
            {
                Counters::add(&self.counters().dropped_scans, 1);
            } else if self.events.is_closed() {
                return Err(DriverError::Shutdown);
            }
        }
    }
}

fn parse_reply<'f>(frame: &'f Frame, what: &'static str) -> Result<Reply<'f>, DriverError> {
    Reply::parse(frame).map_err(|e| DriverError::BadReply {
        what,
        why: e.to_string(),
    })
}

fn bad_info(what: &'static str, e: crate::scip::InfoError) -> DriverError {
    DriverError::BadReply {
        what,
        why: e.to_string(),
    }
}
