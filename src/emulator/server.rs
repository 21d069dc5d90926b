//! The emulator's I/O edge: accepts connections, feeds command lines to the [`Unit`], sends
//! scan blocks when they are due and injects the configured faults. All time comes from tokio's
//! clock, so tests can pause and advance it.

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use thiserror::Error;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::TcpListener;
use tokio::sync::watch;
use tokio::time::Instant;

use super::faults::{EmulatorStats, Faults, GARBAGE};
use super::gate::ReplayGate;
use super::playback::Playback;
use super::unit::{ClockSetting, SourceScan, SyntheticEchoes, Unit};
use crate::scan::{Scan, SensorInfo};
use crate::scip::reply::encode_status;

#[derive(Debug, Error)]
#[non_exhaustive]
pub enum EmulatorError {
    #[error(
        "sensor {0:?} has no PP geometry (DMIN, AMAX, SCAN, …); the emulator needs it to answer PP and scans"
    )]
    NoGeometry(String),
    #[error("sensor {0:?} has no scans to serve")]
    NoScans(String),
    #[error("connection: {0}")]
    Io(#[from] std::io::Error),
}

/// How to play the recording.
#[derive(Debug, Clone, PartialEq)]
pub struct EmulatorConfig {
    /// Playback speed; 2.0 sends scans twice as often as recorded.
    pub speed: f64,
    /// Start over after the last scan instead of ending.
    pub looping: bool,
    pub faults: Faults,
    /// Where the sensor's ms clock starts and how it drifts.
    pub clock: ClockSetting,
    /// Made-up second echoes in multi-echo scans (off by default).
    pub synthetic_echoes: Option<SyntheticEchoes>,
    /// Play on a replay's shared clock instead of this emulator's own (`speed` is then the
    /// gate's): scans fall due at their recorded time and carry it as their stamp.
    pub gate: Option<Gated>,
}

/// An emulator on a [`ReplayGate`].
#[derive(Debug, Clone, PartialEq)]
pub struct Gated {
    pub gate: ReplayGate,
    /// The name it goes by on the gate (the pipeline's sensor id).
    pub id: String,
    /// The recorded stamp (ns) at stream offset 0: the earliest first scan of the replay.
    pub origin_ns: u64,
    /// Every recording of the replay loops with this period (ns), so that the sensors of one
    /// site stay in step loop after loop (their own lengths differ by a scan period or so).
    pub pass_ns: u64,
}

impl Default for EmulatorConfig {
    fn default() -> Self {
        EmulatorConfig {
            speed: 1.0,
            looping: false,
            faults: Faults::default(),
            clock: ClockSetting::default(),
            synthetic_echoes: None,
            gate: None,
        }
    }
}

#[derive(Debug, Default)]
struct FaultState {
    stats: EmulatorStats,
    drop_done: bool,
    stall_done: bool,
}

struct Shared {
    /// Each connection gets a fresh copy, as a unit drops its stream when its client leaves.
    unit: Unit,
    sources: Vec<SourceScan>,
    playback: Playback,
    faults: Faults,
    boot: Instant,
    /// Playback starts with the first scan command, so a client that connects late still gets
    /// the recording from its first scan.
    play_start: Mutex<Option<Instant>>,
    state: Mutex<FaultState>,
    finished: watch::Sender<bool>,
    /// The replay clock, this sensor's id on it, and its first scan's offset on it (ns).
    gate: Option<(ReplayGate, String, u64)>,
    /// Whether a client has joined the gate yet.
    joined: Mutex<bool>,
}

/// One emulated sensor; cheap to clone (shared state).
#[derive(Clone)]
pub struct Emulator {
    shared: Arc<Shared>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A poisoned lock only means another connection task panicked; the data is still usable.
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl Emulator {
    pub fn new(
        info: &SensorInfo,
        scans: &[Scan],
        config: EmulatorConfig,
    ) -> Result<Self, EmulatorError> {
        let geometry = info
            .geometry
            .ok_or_else(|| EmulatorError::NoGeometry(info.id.clone()))?;
        if scans.is_empty() {
            return Err(EmulatorError::NoScans(info.id.clone()));
        }
        let no_returns = config.faults.no_returns;
        let sources = scans
            .iter()
            .map(|s| {
                let mut source = SourceScan::from_scan(s, &geometry);
                if no_returns {
                    source.ranges_mm.fill(0);
                    source.intensities.fill(0);
                }
                source
            })
            .collect();
        // On a gate the speed is the gate's: the playback keeps recorded time.
        let speed = if config.gate.is_some() {
            1.0
        } else {
            config.speed
        };
        let playback = Playback::new(scans, geometry.period_s() * 1000.0, speed, config.looping);
        let playback = match &config.gate {
            Some(g) if config.looping => playback.with_pass_ms(g.pass_ns as f64 / 1e6),
            _ => playback,
        };
        let first_ns = scans.first().map_or(0, |s| s.stamp_ns);
        let gate = config
            .gate
            .map(|g| (g.gate, g.id, first_ns.saturating_sub(g.origin_ns)));
        let (finished, _) = watch::channel(false);
        let mut unit = Unit::new(info, geometry);
        if config.faults.no_multi_echo {
            unit = unit.without_multi_echo();
        }
        Ok(Emulator {
            shared: Arc::new(Shared {
                unit: unit
                    .booting_until(
                        config
                            .faults
                            .booting_for
                            .map_or(0, |d| d.as_millis() as u64),
                    )
                    .with_clock(config.clock)
                    .with_synthetic_echoes(config.synthetic_echoes),
                sources,
                playback,
                faults: config.faults,
                boot: Instant::now(),
                play_start: Mutex::new(None),
                state: Mutex::new(FaultState::default()),
                finished,
                gate,
                joined: Mutex::new(false),
            }),
        })
    }

    pub fn stats(&self) -> EmulatorStats {
        lock(&self.shared.state).stats
    }

    /// Resolves once a non-looping recording has been served to its end.
    pub async fn finished(&self) {
        let mut rx = self.shared.finished.subscribe();
        let _ = rx.wait_for(|done| *done).await;
    }

    fn now_ms(&self) -> u64 {
        self.shared.boot.elapsed().as_millis() as u64
    }

    /// Accepts connections until the recording ends (never, when looping).
    pub async fn serve(&self, listener: TcpListener) -> Result<(), EmulatorError> {
        let mut finished = self.shared.finished.subscribe();
        loop {
            let (socket, peer) = tokio::select! {
                accepted = listener.accept() => accepted?,
                _ = finished.wait_for(|done| *done) => return Ok(()),
            };
            let refusing = self
                .shared
                .faults
                .refuse_for
                .is_some_and(|t| self.shared.boot.elapsed() < t);
            {
                let mut state = lock(&self.shared.state);
                state.stats.connections += 1;
                if refusing {
                    state.stats.refused += 1;
                }
            }
            if refusing {
                tracing::debug!(%peer, "refusing connection (fault injection)");
                drop(socket);
                continue;
            }
            let _ = socket.set_nodelay(true);
            let emulator = self.clone();
            tokio::spawn(async move {
                if let Err(err) = emulator.serve_stream(socket).await {
                    tracing::debug!(%peer, %err, "emulator connection ended");
                }
            });
        }
    }

    /// Serves one client over any byte stream (a TCP socket, a pty bridge).
    pub async fn serve_stream<S: AsyncRead + AsyncWrite + Unpin>(
        &self,
        stream: S,
    ) -> Result<(), EmulatorError> {
        let (mut rd, mut wr) = tokio::io::split(stream);
        let mut unit = self.shared.unit.clone();
        let result = self.connection(&mut unit, &mut rd, &mut wr).await;
        let _ = wr.shutdown().await;
        result
    }

    /// Serves one client over a serial port (a pty in tests).
    pub async fn serve_serial(
        &self,
        port: Box<dyn serialport::SerialPort>,
    ) -> Result<(), EmulatorError> {
        let stream = crate::sensor::transport::bridge(port)?;
        self.serve_stream(stream).await
    }

    async fn connection<R: AsyncRead + Unpin, W: AsyncWrite + Unpin>(
        &self,
        unit: &mut Unit,
        rd: &mut R,
        wr: &mut W,
    ) -> Result<(), EmulatorError> {
        let shared = &self.shared;
        let mut pending: Vec<u8> = Vec::new();
        let mut chunk = [0u8; 1024];
        let mut streams_seen = unit.streams_started();
        let reboots_seen = unit.reboots();
        let mut next_k: u64 = 0;
        loop {
            let due = if unit.is_streaming() {
                match self.due(next_k) {
                    Some(due) => due,
                    None => {
                        // A non-looping recording has been played to its end.
                        if let Some((gate, id, _)) = &shared.gate {
                            gate.finished(id);
                        }
                        let _ = shared.finished.send(true);
                        return Ok(());
                    }
                }
            } else {
                Due::Never
            };
            let wait = async {
                match &due {
                    Due::At(at) => tokio::time::sleep_until(*at).await,
                    Due::OnGate(gate, offset_ns) => gate.wait_until(*offset_ns).await,
                    Due::Never => std::future::pending().await,
                }
            };
            tokio::select! {
                n = rd.read(&mut chunk) => {
                    let n = n?;
                    if n == 0 {
                        lock(&shared.state).stats.client_closes += 1;
                        return Ok(());
                    }
                    pending.extend_from_slice(chunk.get(..n).unwrap_or_default());
                    while let Some(end) = pending.iter().position(|&b| b == b'\n' || b == b'\r') {
                        let line: Vec<u8> = pending.drain(..=end).take(end).collect();
                        if line.is_empty() {
                            continue; // the other half of a CR LF
                        }
                        let reply = self.answer(unit, &line);
                        wr.write_all(&reply).await?;
                        if unit.reboots() != reboots_seen {
                            // A rebooting unit restarts: the connection goes with it.
                            lock(&shared.state).stats.reboots += 1;
                            wr.flush().await?;
                            tracing::info!("rebooted (RB twice); dropping the connection");
                            return Ok(());
                        }
                        let started = unit.streams_started();
                        if started != streams_seen {
                            streams_seen = started;
                            next_k = self.first_due_after_now();
                        }
                    }
                }
                _ = wait => {
                    if !self.emit(unit, wr, &mut next_k).await? {
                        return Ok(());
                    }
                }
            }
        }
    }

    /// When sequence number `k` falls due; `None` past the end of a non-looping recording.
    fn due(&self, k: u64) -> Option<Due> {
        let shared = &self.shared;
        if let Some((gate, _, shift_ns)) = &shared.gate {
            let offset_ns = shift_ns + (shared.playback.due_ms(k)? * 1e6) as u64;
            return Some(Due::OnGate(gate.clone(), offset_ns));
        }
        let due_ms = shared.playback.due_ms(k)?;
        Some(match *lock(&shared.play_start) {
            Some(start) => Due::At(start + Duration::from_secs_f64(due_ms / 1000.0)),
            None => Due::Never,
        })
    }

    fn answer(&self, unit: &mut Unit, line: &[u8]) -> Vec<u8> {
        let shared = &self.shared;
        if line.starts_with(b"QT") {
            lock(&shared.state).stats.quits += 1;
            if unit.is_streaming() {
                // A client that stops the laser before leaving says so in the log.
                tracing::info!("QT while streaming: the client stopped the laser");
            }
        }
        if let Some(needed) = shared.faults.abnormal_until_reboots {
            let mut state = lock(&shared.state);
            let exempt = matches!(line.get(..2), Some(b"RB" | b"QT" | b"VV" | b"PP" | b"II"));
            if state.stats.reboots < u64::from(needed) && !exempt {
                state.stats.abnormal_answers += 1;
                return encode_status(line, *b"0L");
            }
        }
        let now_ms = self.now_ms();
        let current = self
            .current_k()
            .and_then(|k| shared.playback.index(k))
            .and_then(|i| shared.sources.get(i));
        unit.handle(line, now_ms, current.or(shared.sources.first()))
    }

    /// Time into this recording's playback, ms (recorded time on a gate); `None` before it
    /// started.
    fn played_ms(&self) -> Option<f64> {
        match &self.shared.gate {
            Some((gate, _, shift_ns)) => (*lock(&self.shared.joined))
                .then(|| (gate.now_ns() as f64 - *shift_ns as f64) / 1e6),
            None => {
                let start = (*lock(&self.shared.play_start))?;
                Some(start.elapsed().as_secs_f64() * 1000.0)
            }
        }
    }

    fn current_k(&self) -> Option<u64> {
        self.shared.playback.current(self.played_ms()?)
    }

    /// Sequence number a new stream starts with: the first scan if playback has not started,
    /// else the next one to fall due.
    fn first_due_after_now(&self) -> u64 {
        let shared = &self.shared;
        if let Some((gate, id, shift_ns)) = &shared.gate {
            let mut joined = lock(&shared.joined);
            if !*joined {
                *joined = true;
                drop(joined);
                gate.join(id, *shift_ns);
                // A gate on the wall clock is under way: join it where it stands.
                if !gate.is_anchored() {
                    return 0;
                }
            }
        } else {
            let mut start = lock(&shared.play_start);
            if start.is_none() {
                *start = Some(Instant::now());
                return 0;
            }
        }
        match self.played_ms() {
            // Before this recording's first scan (a later start than another's).
            Some(ms) if ms < 0.0 => 0,
            Some(ms) => shared.playback.current(ms).map_or(0, |k| k + 1),
            None => 0,
        }
    }

    /// The sensor clock stamped on sequence number `k`: on a gate its recorded time (ms from
    /// the replay's origin), else when it was due on the clock of [`Self::now_ms`].
    fn stamp_ms(&self, k: u64, now_ms: u64) -> u64 {
        let shared = &self.shared;
        if let Some((_, _, shift_ns)) = &shared.gate {
            let due_ms = shared.playback.due_ms(k).unwrap_or(0.0);
            return ((*shift_ns as f64 / 1e6) + due_ms).round() as u64;
        }
        let Some(start) = *lock(&shared.play_start) else {
            return now_ms;
        };
        let Some(offset_ms) = start
            .checked_duration_since(shared.boot)
            .map(|d| d.as_secs_f64() * 1000.0)
        else {
            return now_ms;
        };
        shared
            .playback
            .due_ms(k)
            .map_or(now_ms, |due| ((offset_ms + due) as u64).min(now_ms))
    }

    /// Sends the block for `next_k` (or the latest scan if this connection fell behind).
    /// Returns `false` when a fault closes the connection.
    async fn emit<W: AsyncWrite + Unpin>(
        &self,
        unit: &mut Unit,
        wr: &mut W,
        next_k: &mut u64,
    ) -> Result<bool, EmulatorError> {
        let shared = &self.shared;
        // A late timer (a busy host) sends the scan late rather than losing it.
        let k = *next_k;
        *next_k = k + 1;
        let Some(source) = shared.playback.index(k).and_then(|i| shared.sources.get(i)) else {
            return Ok(true);
        };
        // A real unit stamps a scan when it measures it, not when it is sent: a block sent late
        // by a busy host keeps the time it was due.
        let stamp_ms = self.stamp_ms(k, self.now_ms());
        let block = if shared.gate.is_some() {
            unit.stream_block_stamped(source, (stamp_ms & 0xFF_FFFF) as u32)
        } else {
            unit.stream_block(source, stamp_ms)
        };
        let Some(mut block) = block else {
            return Ok(true);
        };
        let faults = &shared.faults;
        let (garbage, drop_now, stall) = {
            let mut state = lock(&shared.state);
            state.stats.scans_sent += 1;
            let n = state.stats.scans_sent;
            let every = |e: Option<u64>| e.is_some_and(|e| e > 0 && n.is_multiple_of(e));
            if every(faults.corrupt_every) && corrupt(&mut block) {
                state.stats.corrupted += 1;
            }
            let garbage = every(faults.garbage_every);
            if garbage {
                state.stats.garbage_bursts += 1;
            }
            let drop_now = !state.drop_done && faults.drop_after_scans.is_some_and(|d| n >= d);
            if drop_now {
                state.drop_done = true;
                state.stats.dropped += 1;
            }
            let stall = match faults.stall {
                Some((after, duration)) if !state.stall_done && n >= after => {
                    state.stall_done = true;
                    state.stats.stalls += 1;
                    Some(duration)
                }
                _ => None,
            };
            (garbage, drop_now, stall)
        };
        if garbage {
            wr.write_all(GARBAGE).await?;
        }
        wr.write_all(&block).await?;
        wr.flush().await?;
        if drop_now {
            return Ok(false);
        }
        if let Some(duration) = stall {
            tokio::time::sleep(duration).await;
            // A stalled unit does not queue what it measured meanwhile: go on with the newest.
            if let Some(current) = self.current_k() {
                *next_k = (*next_k).max(current);
            }
        }
        Ok(true)
    }
}

/// What a connection waits for before its next scan.
enum Due {
    At(Instant),
    OnGate(ReplayGate, u64),
    Never,
}

/// Breaks the checksum of the first data line of a scan block; `false` if it has none.
fn corrupt(block: &mut [u8]) -> bool {
    // Lines: echo, status, timestamp, data…; the first data line ends at the 4th LF.
    let Some(end) = block
        .iter()
        .enumerate()
        .filter(|(_, b)| **b == b'\n')
        .nth(3)
        .map(|(i, _)| i)
    else {
        return false;
    };
    match end.checked_sub(1).and_then(|i| block.get_mut(i)) {
        Some(sum) if *sum != b'\n' => {
            // Stay inside the checksum alphabet so only the value is wrong.
            *sum = if *sum == 0x6F { 0x30 } else { *sum + 1 };
            true
        }
        _ => false,
    }
}
