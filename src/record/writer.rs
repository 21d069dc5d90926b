//! Writes recordings. The file grows as `<name>.partial` and is renamed into place only by
//! [`RecordingWriter::finish`], after an fsync: a finished recording is never half-written, and
//! an interrupted one is still readable up to where it stopped.

use std::collections::HashMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use mcap::records::Metadata;
use prost::Message as _;

use super::laserscan::{self, LaserScan, Pose, Timestamp};
use super::metadata::{MOVE_RECORD, SENSOR_RECORD, move_to_map, sensor_to_map};
use super::{PEOPLE_TRUTH_TOPIC, RecordError, scan_topic, scip_topic};
use crate::scan::{MoveTruth, PeopleTruth, Scan, SensorInfo, check_sensor_id};

/// Schema name of `/truth/people` messages (JSON).
pub const PEOPLE_TRUTH_SCHEMA: &str = "scanfuse.PeopleTruth";

/// JSON Schema of `/truth/people`, so that Foxglove and other readers know its fields.
const PEOPLE_TRUTH_JSON_SCHEMA: &str = r#"{"type":"object","title":"scanfuse.PeopleTruth","description":"Every simulated person's body centre, site frame; ground truth for evaluation only","properties":{"t_ns":{"type":"integer","description":"recording time, ns since the Unix epoch"},"people":{"type":"array","items":{"type":"object","properties":{"id":{"type":"string"},"x_m":{"type":"number"},"y_m":{"type":"number"}},"required":["id","x_m","y_m"]}}},"required":["t_ns","people"]}"#;

/// Message encoding of raw SCIP byte channels.
pub const SCIP_ENCODING: &str = "scip2";

/// Fast enough for dozens of live sensors on one core.
pub const DEFAULT_ZSTD_LEVEL: u32 = 3;

/// Chunks are kept small so that a crash or a cut file loses at most a fraction of a second.
const CHUNK_SIZE_BYTES: u64 = 256 * 1024;

pub struct RecordingWriter {
    path: PathBuf,
    partial: PathBuf,
    mcap: mcap::Writer<BufWriter<File>>,
    schema_id: u16,
    scan_channels: HashMap<String, Channel>,
    scip_channels: HashMap<String, Channel>,
    people_truth: Option<Channel>,
}

struct Channel {
    id: u16,
    sequence: u32,
}

impl RecordingWriter {
    /// Starts `<path>.partial`; nothing appears at `path` until [`finish`](Self::finish).
    pub fn create(path: &Path) -> Result<Self, RecordError> {
        Self::create_with_level(path, DEFAULT_ZSTD_LEVEL)
    }

    /// Like [`create`](Self::create) with a zstd level (1–22): 19 makes fixtures ~17 % smaller
    /// but compresses at a few MB/s, too slow to keep up with live sensors.
    pub fn create_with_level(path: &Path, zstd_level: u32) -> Result<Self, RecordError> {
        let partial = partial_path(path);
        let io = |source| RecordError::Io {
            path: partial.clone(),
            source,
        };
        let file = File::create(&partial).map_err(io)?;
        let mut mcap = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .compression_level(zstd_level.clamp(1, 22))
            .chunk_size(Some(CHUNK_SIZE_BYTES))
            .profile("")
            .library(concat!("scanfuse ", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::new(file))
            .map_err(|e| mcap_error(&partial, e))?;
        let schema_id = mcap
            .add_schema(
                laserscan::SCHEMA_NAME,
                laserscan::ENCODING,
                laserscan::SCHEMA_DESCRIPTOR,
            )
            .map_err(|e| mcap_error(&partial, e))?;
        Ok(RecordingWriter {
            path: path.to_path_buf(),
            partial,
            mcap,
            schema_id,
            scan_channels: HashMap::new(),
            scip_channels: HashMap::new(),
            people_truth: None,
        })
    }

    /// Declares a sensor: its `scanfuse.sensor` metadata record and its scan channel.
    pub fn add_sensor(&mut self, sensor: &SensorInfo) -> Result<(), RecordError> {
        check_sensor_id(&sensor.id).map_err(|what| self.invalid(what))?;
        if self.scan_channels.contains_key(&sensor.id) {
            return Err(self.invalid(format!("sensor {} added twice", sensor.id)));
        }
        self.mcap
            .write_metadata(&Metadata {
                name: SENSOR_RECORD.into(),
                metadata: sensor_to_map(sensor),
            })
            .map_err(|e| mcap_error(&self.partial, e))?;
        let id = self
            .mcap
            .add_channel(
                self.schema_id,
                &scan_topic(&sensor.id),
                laserscan::ENCODING,
                &Default::default(),
            )
            .map_err(|e| mcap_error(&self.partial, e))?;
        self.scan_channels
            .insert(sensor.id.clone(), Channel { id, sequence: 0 });
        Ok(())
    }

    /// Appends one scan of a sensor declared with [`add_sensor`](Self::add_sensor).
    pub fn write_scan(&mut self, sensor_id: &str, scan: &Scan) -> Result<(), RecordError> {
        if !scan.intensities.is_empty() && scan.intensities.len() != scan.ranges_m.len() {
            return Err(self.invalid(format!(
                "sensor {sensor_id}: scan has {} intensities for {} ranges",
                scan.intensities.len(),
                scan.ranges_m.len()
            )));
        }
        let message = LaserScan {
            timestamp: Some(Timestamp::from_ns(scan.stamp_ns)),
            frame_id: sensor_id.to_string(),
            pose: Some(Pose::identity()),
            start_angle: scan.start_angle_rad,
            end_angle: scan.end_angle_rad,
            ranges: scan.ranges_m.iter().map(|r| metres_f64(*r)).collect(),
            intensities: scan.intensities.iter().map(|i| f64::from(*i)).collect(),
        };
        let Some(channel) = self.scan_channels.get_mut(sensor_id) else {
            return Err(self.invalid(format!("sensor {sensor_id} was never added")));
        };
        write(
            &mut self.mcap,
            &self.partial,
            channel,
            scan.stamp_ns,
            &message.encode_to_vec(),
        )
    }

    /// Appends raw SCIP bytes read from a sensor, on `/<id>/scip`.
    pub fn write_scip(
        &mut self,
        sensor_id: &str,
        stamp_ns: u64,
        bytes: &[u8],
    ) -> Result<(), RecordError> {
        if !self.scan_channels.contains_key(sensor_id) {
            return Err(self.invalid(format!("sensor {sensor_id} was never added")));
        }
        if !self.scip_channels.contains_key(sensor_id) {
            let id = self
                .mcap
                .add_channel(
                    0,
                    &scip_topic(sensor_id),
                    SCIP_ENCODING,
                    &Default::default(),
                )
                .map_err(|e| mcap_error(&self.partial, e))?;
            self.scip_channels
                .insert(sensor_id.to_string(), Channel { id, sequence: 0 });
        }
        let Some(channel) = self.scip_channels.get_mut(sensor_id) else {
            return Err(self.invalid(format!("sensor {sensor_id} has no SCIP channel")));
        };
        write(&mut self.mcap, &self.partial, channel, stamp_ns, bytes)
    }

    /// Appends where every simulated person is, on `/truth/people` (JSON; declared with its
    /// schema at the first message).
    pub fn write_people_truth(&mut self, truth: &PeopleTruth) -> Result<(), RecordError> {
        if self.people_truth.is_none() {
            let schema_id = self
                .mcap
                .add_schema(
                    PEOPLE_TRUTH_SCHEMA,
                    "jsonschema",
                    PEOPLE_TRUTH_JSON_SCHEMA.as_bytes(),
                )
                .map_err(|e| mcap_error(&self.partial, e))?;
            let id = self
                .mcap
                .add_channel(schema_id, PEOPLE_TRUTH_TOPIC, "json", &Default::default())
                .map_err(|e| mcap_error(&self.partial, e))?;
            self.people_truth = Some(Channel { id, sequence: 0 });
        }
        let data = serde_json::to_vec(truth)
            .map_err(|e| self.invalid(format!("cannot encode the people's truth: {e}")))?;
        let Some(channel) = self.people_truth.as_mut() else {
            return Err(self.invalid("no /truth/people channel".into()));
        };
        write(&mut self.mcap, &self.partial, channel, truth.t_ns, &data)
    }

    /// Records the true pose of a sensor after it was moved (simulations).
    pub fn add_move(&mut self, moved: &MoveTruth) -> Result<(), RecordError> {
        self.mcap
            .write_metadata(&Metadata {
                name: MOVE_RECORD.into(),
                metadata: move_to_map(moved),
            })
            .map_err(|e| mcap_error(&self.partial, e))
    }

    /// Writes the summary, syncs to disk and renames `<path>.partial` to `path`.
    pub fn finish(mut self) -> Result<(), RecordError> {
        self.mcap
            .finish()
            .map_err(|e| mcap_error(&self.partial, e))?;
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| RecordError::Io { path, source }
        };
        let file = self
            .mcap
            .into_inner()
            .into_inner()
            .map_err(|e| e.into_error())
            .map_err(io(&self.partial))?;
        file.sync_all().map_err(io(&self.partial))?;
        std::fs::rename(&self.partial, &self.path).map_err(io(&self.path))?;
        if let Some(dir) = self.path.parent().filter(|d| !d.as_os_str().is_empty()) {
            // Make the rename itself durable; failure here loses nothing already written.
            if let Ok(dir) = File::open(dir) {
                let _ = dir.sync_all();
            }
        }
        Ok(())
    }

    fn invalid(&self, what: String) -> RecordError {
        RecordError::Invalid {
            path: self.partial.clone(),
            what,
        }
    }
}

fn write(
    mcap: &mut mcap::Writer<BufWriter<File>>,
    path: &Path,
    channel: &mut Channel,
    stamp_ns: u64,
    data: &[u8],
) -> Result<(), RecordError> {
    mcap.write_to_known_channel(
        &mcap::records::MessageHeader {
            channel_id: channel.id,
            sequence: channel.sequence,
            log_time: stamp_ns,
            publish_time: stamp_ns,
        },
        data,
    )
    .map_err(|e| mcap_error(path, e))?;
    channel.sequence = channel.sequence.wrapping_add(1);
    Ok(())
}

/// The `.partial` file a recording grows in.
pub fn partial_path(path: &Path) -> PathBuf {
    let mut name = path.as_os_str().to_owned();
    name.push(".partial");
    PathBuf::from(name)
}

/// f32 metres as the f64 a reader expects: rounded to the µm, so 3.001 m (from 3001 mm) is
/// stored as the double nearest 3.001 rather than as f32's 3.0009999275.
fn metres_f64(range_m: f32) -> f64 {
    if range_m.is_finite() {
        (f64::from(range_m) * 1e6).round() / 1e6
    } else {
        f64::from(range_m)
    }
}

fn mcap_error(path: &Path, err: mcap::McapError) -> RecordError {
    RecordError::Invalid {
        path: path.to_path_buf(),
        what: format!("writing MCAP: {err}"),
    }
}
