//! `scanfuse record --connect URI --id ID --out FILE.mcap [--seconds S]`: records a live
//! sensor (or `scanfuse emulate`) into the recording format, raw SCIP kept on `/<id>/scip`.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context as _;
use scanfuse::record::RecordingWriter;
use scanfuse::sensor::{Driver, DriverConfig, DriverEvent, ScanMode};
use tokio::sync::{mpsc, watch};

use super::BadInput;

#[derive(clap::Args)]
pub struct Args {
    /// Sensor address: tcp://HOST:PORT or serial:///dev/ttyACM0[?baud=N].
    #[arg(long)]
    connect: String,
    /// Sensor id (the recording's topic prefix).
    #[arg(long)]
    id: String,
    /// Recording to write.
    #[arg(long)]
    out: PathBuf,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long)]
    seconds: Option<f64>,
    /// Stop after this many scans.
    #[arg(long)]
    scans: Option<u64>,
    /// Stream to record: MD (ranges), ME (ranges + intensities), ND, NE (multi-echo).
    #[arg(long, default_value = "ME")]
    mode: String,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let mode = ScanMode::parse(&args.mode)
        .ok_or_else(|| BadInput(format!("--mode {:?}: use MD, ME, ND or NE", args.mode)))?;
    let limit = match args.seconds {
        Some(s) if !(s.is_finite() && s > 0.0) => {
            return Err(BadInput(format!("--seconds {s} must be a positive number")).into());
        }
        Some(s) => Some(Duration::from_secs_f64(s)),
        None => None,
    };
    let mut config = DriverConfig::new(args.id.clone(), args.connect.clone());
    config.mode = mode;
    config.raw = true;
    scanfuse::sensor::Endpoint::parse(&args.connect).map_err(|e| BadInput(e.to_string()))?;
    let mut writer = RecordingWriter::create(&args.out)?;
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let written = runtime.block_on(async {
        let driver = Driver::new(config);
        let counters = driver.counters();
        let (tx, mut rx) = mpsc::channel(1024);
        let (stop, stop_rx) = watch::channel(false);
        let task = tokio::spawn(driver.run(tx, stop_rx));
        let deadline = limit.map(|l| tokio::time::Instant::now() + l);
        let mut added = false;
        // Bytes read before the handshake finished belong to the recording too.
        let mut early_raw: Vec<(u64, Vec<u8>)> = Vec::new();
        let mut scans = 0u64;
        // Why the sensor last dropped or failed, for the error when nothing was recorded.
        let mut last_reason: Option<String> = None;
        let mut failed = false;
        loop {
            let sleep = tokio::time::sleep_until(
                deadline
                    .unwrap_or_else(|| tokio::time::Instant::now() + Duration::from_secs(86_400)),
            );
            let event = tokio::select! {
                e = rx.recv() => e,
                _ = sleep => break,
                _ = tokio::signal::ctrl_c() => break,
            };
            let Some(event) = event else { break };
            match event {
                DriverEvent::Connected(info) => {
                    if !added {
                        writer.add_sensor(&info)?;
                        added = true;
                        for (stamp_ns, bytes) in early_raw.drain(..) {
                            writer.write_scip(&args.id, stamp_ns, &bytes)?;
                        }
                    }
                    tracing::info!(sensor = %args.id, model = %info.model, "recording");
                }
                DriverEvent::Raw { stamp_ns, bytes } => {
                    if added {
                        writer.write_scip(&args.id, stamp_ns, &bytes)?;
                    } else {
                        early_raw.push((stamp_ns, bytes));
                    }
                }
                DriverEvent::Scan(scan) => {
                    if added {
                        writer.write_scan(&args.id, &scan.scan)?;
                        scans += 1;
                        if args.scans.is_some_and(|n| scans >= n) {
                            break;
                        }
                    }
                }
                DriverEvent::Disconnected { reason } => {
                    tracing::warn!(sensor = %args.id, %reason, "sensor link lost");
                    last_reason = Some(reason);
                }
                DriverEvent::Failed { reason } => {
                    // The driver has given up; waiting longer records nothing more.
                    last_reason = Some(reason);
                    failed = true;
                    break;
                }
            }
        }
        let _ = stop.send(true);
        let _ = task.await;
        let c = counters.snapshot();
        tracing::info!(
            scans,
            checksum_errors = c.checksum_errors,
            reconnects = c.reconnects,
            skipped_bytes = c.skipped_bytes,
            "recording done"
        );
        anyhow::Ok((added, scans, last_reason, failed))
    })?;
    let (added, scans, last_reason, failed) = written;
    if !added || scans == 0 {
        // Nothing worth keeping: no file is left that looks like a recording.
        drop(writer);
        let _ = std::fs::remove_file(scanfuse::record::partial_path(&args.out));
        let why = match (last_reason, added) {
            (Some(reason), _) => reason,
            (None, false) => "no sensor answered".to_string(),
            (None, true) => "the sensor connected but sent no scans".to_string(),
        };
        anyhow::bail!(
            "nothing recorded from {}, {} not written: {why}",
            args.connect,
            args.out.display()
        );
    }
    writer
        .finish()
        .with_context(|| format!("finishing {}", args.out.display()))?;
    println!("{}: {scans} scans from {}", args.out.display(), args.id);
    if failed {
        anyhow::bail!(
            "the recording stops early: {}",
            last_reason.unwrap_or_default()
        );
    }
    Ok(())
}
