//! `scanfuse emulate FILE.mcap --sensor ID --listen 127.0.0.1:PORT`: serves one sensor of a
//! recording over TCP as a live SCIP 2.0 unit. With port 0 the bound address is printed on
//! stdout (one line) so scripts and tests can connect.

use std::io::Write as _;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context as _;
use scanfuse::emulator::{ClockSetting, Emulator, EmulatorConfig, Faults, SyntheticEchoes};
use scanfuse::record;
use serialport::SerialPort as _;

use super::BadInput;

#[derive(clap::Args)]
pub struct Args {
    /// Recording to serve.
    file: PathBuf,
    /// Sensor id to serve (may be left out when the recording has one sensor).
    #[arg(long)]
    sensor: Option<String>,
    /// Address to listen on; port 0 picks a free port and prints the address.
    #[arg(long, default_value = "127.0.0.1:10940")]
    listen: SocketAddr,
    /// Serve on a new pseudo-terminal instead of TCP, as a USB unit would; prints its path.
    #[arg(long, conflicts_with = "listen")]
    pty: bool,
    /// Playback speed (2 = twice the recorded rate).
    #[arg(long, default_value_t = 1.0)]
    speed: f64,
    /// Start over after the last scan instead of ending.
    #[arg(long = "loop")]
    looping: bool,
    /// Fault: close the connection after N scans (once).
    #[arg(long, value_name = "N")]
    drop_after: Option<u64>,
    /// Fault: break one checksum in every Nth scan block.
    #[arg(long, value_name = "N")]
    corrupt_every: Option<u64>,
    /// Fault: after N scans, go silent for --stall-ms (once).
    #[arg(long, value_name = "N", requires = "stall_ms")]
    stall_after: Option<u64>,
    /// Length of the stall, ms.
    #[arg(long, value_name = "MS", requires = "stall_after")]
    stall_ms: Option<u64>,
    /// Fault: send junk bytes before every Nth scan block.
    #[arg(long, value_name = "N")]
    garbage_every: Option<u64>,
    /// Fault: close every connection for the first MS ms.
    #[arg(long, value_name = "MS")]
    refuse_ms: Option<u64>,
    /// Fault: refuse TM0 and scans (status 10) for the first MS ms, like a booting unit.
    #[arg(long, value_name = "MS")]
    booting_ms: Option<u64>,
    /// Fault: answer 0L (abnormal state) to all but RB QT VV PP II until rebooted (RB twice)
    /// N times; each reboot drops the connection. 4294967295: never recovers.
    #[arg(long, value_name = "N")]
    abnormal_until_reboots: Option<u32>,
    /// Fault: answer 0E (undefined command) to ND NE HD HE, like a unit without multi-echo.
    #[arg(long)]
    no_multi_echo: bool,
    /// Fault: every range of every scan is 0 (no return), like a unit with a covered window.
    #[arg(long)]
    no_returns: bool,
    /// Sensor clock reading at start and after each reset (RS/RT/RB), ms; e.g. 16775000 puts
    /// the 24-bit wrap (16777216) two seconds after the driver's handshake. Real units start at 0.
    #[arg(long, value_name = "MS", default_value_t = 0)]
    clock_start_ms: u64,
    /// Sensor clock drift against the host, parts per million (positive runs fast).
    #[arg(
        long,
        value_name = "PPM",
        default_value_t = 0.0,
        allow_negative_numbers = true
    )]
    clock_drift_ppm: f64,
    /// Make up a second echo, 500 mm behind the first, for every Nth value of multi-echo
    /// scans (ND NE HD HE): recordings hold one echo per step. For testing clients.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    synthetic_echoes: Option<u32>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if !(args.speed.is_finite() && args.speed > 0.0) {
        return Err(BadInput(format!("--speed {} must be a positive number", args.speed)).into());
    }
    if !(args.clock_drift_ppm.is_finite() && args.clock_drift_ppm.abs() < 1e6) {
        return Err(BadInput(format!(
            "--clock-drift-ppm {} must be a number between -1000000 and 1000000",
            args.clock_drift_ppm
        ))
        .into());
    }
    let recording = record::read(&args.file)?;
    let sensor = match (&args.sensor, recording.sensors.as_slice()) {
        (Some(id), _) => recording.sensor(id).ok_or_else(|| {
            let ids: Vec<&str> = recording.sensors.iter().map(|s| s.id.as_str()).collect();
            BadInput(format!(
                "{}: no sensor {id:?}; it has {}",
                args.file.display(),
                ids.join(", ")
            ))
        })?,
        (None, [only]) => only,
        (None, sensors) => {
            let ids: Vec<&str> = sensors.iter().map(|s| s.id.as_str()).collect();
            return Err(BadInput(format!(
                "{} has {} sensors ({}); choose one with --sensor",
                args.file.display(),
                sensors.len(),
                ids.join(", ")
            ))
            .into());
        }
    };
    let config = EmulatorConfig {
        speed: args.speed,
        looping: args.looping,
        faults: Faults {
            drop_after_scans: args.drop_after,
            corrupt_every: args.corrupt_every,
            stall: args
                .stall_after
                .zip(args.stall_ms.map(Duration::from_millis)),
            garbage_every: args.garbage_every,
            refuse_for: args.refuse_ms.map(Duration::from_millis),
            booting_for: args.booting_ms.map(Duration::from_millis),
            abnormal_until_reboots: args.abnormal_until_reboots,
            no_multi_echo: args.no_multi_echo,
            no_returns: args.no_returns,
        },
        clock: ClockSetting {
            start_ms: args.clock_start_ms,
            drift_ppm: args.clock_drift_ppm,
        },
        synthetic_echoes: args.synthetic_echoes.map(|every| SyntheticEchoes {
            every,
            behind_mm: SYNTHETIC_ECHO_BEHIND_MM,
        }),
        ..EmulatorConfig::default()
    };
    let scans = recording.scans_of(&sensor.id);
    let emulator = Emulator::new(sensor, scans, config).map_err(|e| BadInput(e.to_string()))?;
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    if args.pty {
        return runtime.block_on(serve_pty(emulator, &sensor.id));
    }
    runtime.block_on(async {
        let listener = tokio::net::TcpListener::bind(args.listen)
            .await
            .with_context(|| format!("cannot listen on {}", args.listen))?;
        let bound = listener.local_addr()?;
        if args.listen.port() == 0 {
            println!("{bound}");
            std::io::stdout().flush()?;
        }
        tracing::info!(sensor = %sensor.id, scans = scans.len(), %bound, "emulating");
        tokio::select! {
            served = emulator.serve(listener) => served?,
            _ = tokio::signal::ctrl_c() => {}
        }
        tracing::info!(stats = ?emulator.stats(), "emulator done");
        anyhow::Ok(())
    })
}

/// How far behind the first echo `--synthetic-echoes` puts the second.
const SYNTHETIC_ECHO_BEHIND_MM: u32 = 500;

/// Time for the last bytes to reach the pty after the recording ends.
const PTY_DRAIN: Duration = Duration::from_millis(300);

/// One client over a pty: the emulator holds the master, a driver opens the printed slave path.
async fn serve_pty(emulator: Emulator, id: &str) -> anyhow::Result<()> {
    let (master, slave) = serialport::TTYPort::pair().context("cannot open a pseudo-terminal")?;
    let path = slave.name().context("the pseudo-terminal has no name")?;
    println!("{path}");
    std::io::stdout().flush()?;
    tracing::info!(sensor = %id, %path, "emulating on a pty");
    tokio::select! {
        served = emulator.serve_serial(Box::new(master)) => served?,
        _ = tokio::signal::ctrl_c() => {}
    }
    // The serial bridge writes from its own thread: give it time to hand the last reply to
    // the pty before the process exits. The slave end stays open until here so the pty
    // outlives client reconnects.
    tokio::time::sleep(PTY_DRAIN).await;
    drop(slave);
    Ok(())
}
