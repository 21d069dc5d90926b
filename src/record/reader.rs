//! Reads recordings written by scanfuse or by any other MCAP writer.
//!
//! A laser channel is any channel whose schema is `foxglove.LaserScan`, in protobuf or JSON,
//! outside `/truth/`. Ground-truth channels (`/truth/*`) are listed apart and read only by
//! [`read_truth_people`]; other channels are listed as skipped, never fatal. Reading is linear, so a truncated or
//! corrupt file still yields every scan before the damage, with the damage described.

use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

use mcap::records::Record;
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
use prost::Message as _;

use super::laserscan::{self, LaserScan, Timestamp};
use super::metadata::{MOVE_RECORD, SENSOR_RECORD, move_from_map, sensor_from_map};
use super::writer::SCIP_ENCODING;
use super::{PEOPLE_TRUTH_TOPIC, RecordError, TRUTH_PREFIX};
use crate::scan::{MoveTruth, PeopleTruth, Scan, SensorInfo};

/// Everything read from one recording.
#[derive(Debug)]
pub struct Recording {
    pub path: PathBuf,
    /// Sensors in the order the file declares them.
    pub sensors: Vec<SensorInfo>,
    /// Scans per sensor id, in file order.
    pub scans: BTreeMap<String, Vec<Scan>>,
    /// Raw SCIP messages per sensor id (`/<id>/scip`), counted, not kept.
    pub scip_messages: BTreeMap<String, usize>,
    /// True poses after moves (simulated recordings).
    pub moves: Vec<MoveTruth>,
    /// Channels that carry something other than laser scans.
    pub skipped: Vec<SkippedChannel>,
    /// Ground-truth channels (`/truth/*`, simulated recordings), counted, not kept: only
    /// evaluation and tests read them, with [`read_truth_people`].
    pub truth: Vec<SkippedChannel>,
    /// What was wrong with the file, when [`read_lenient`] read it only in part.
    pub damage: Option<RecordError>,
}

/// A channel the reader does not understand, with how many messages it held.
#[derive(Debug, Clone, PartialEq)]
pub struct SkippedChannel {
    pub topic: String,
    pub schema: String,
    pub encoding: String,
    pub messages: usize,
}

impl Recording {
    pub fn sensor(&self, id: &str) -> Option<&SensorInfo> {
        self.sensors.iter().find(|s| s.id == id)
    }

    /// The stamp of the earliest first scan of any sensor: where stream time starts.
    pub fn first_stamp_ns(&self) -> Option<u64> {
        self.scans
            .values()
            .filter_map(|s| s.first())
            .map(|s| s.stamp_ns)
            .min()
    }

    /// The scans of sensor `id`, empty when it has none.
    pub fn scans_of(&self, id: &str) -> &[Scan] {
        self.scans.get(id).map(Vec::as_slice).unwrap_or(&[])
    }
}

/// Reads a whole recording; any damage is an error.
pub fn read(path: &Path) -> Result<Recording, RecordError> {
    let mut recording = read_lenient(path)?;
    match recording.damage.take() {
        Some(damage) => Err(damage),
        None => Ok(recording),
    }
}

/// Reads what can be read. Fails only when the file cannot be opened or is not MCAP at all;
/// otherwise damage is reported in [`Recording::damage`] with every scan before it kept.
pub fn read_lenient(path: &Path) -> Result<Recording, RecordError> {
    let bytes = std::fs::read(path).map_err(|source| RecordError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse(path, &bytes, false).map(|(recording, _)| recording)
}

/// The people's ground truth of a simulated recording (`/truth/people`), in file order; empty
/// when it has none. For evaluation and tests only: nothing in the pipeline may see it. Any
/// damage to the file, or a message that is not the documented JSON, is an error.
pub fn read_truth_people(path: &Path) -> Result<Vec<PeopleTruth>, RecordError> {
    let bytes = std::fs::read(path).map_err(|source| RecordError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let (recording, people) = parse(path, &bytes, true)?;
    match recording.damage {
        Some(damage) => Err(damage),
        None => Ok(people),
    }
}

/// Largest record or decompressed chunk accepted, bytes.
const MAX_RECORD_BYTES: usize = 256 << 20;

enum Kind {
    Laser { sensor_id: String, json: bool },
    Scip { sensor_id: String },
    Skipped(usize),
    Truth(usize),
}

struct Channel {
    topic: String,
    kind: Kind,
}

#[derive(Default)]
struct Parse {
    schemas: HashMap<u16, (String, String)>,
    channels: HashMap<u16, Channel>,
    channel_order: Vec<String>,
    sensors: Vec<SensorInfo>,
    scans: BTreeMap<String, Vec<Scan>>,
    scip_messages: BTreeMap<String, usize>,
    moves: Vec<MoveTruth>,
    skipped: Vec<SkippedChannel>,
    truth: Vec<SkippedChannel>,
    /// Whether `/truth/people` messages are decoded and kept.
    keep_people: bool,
    people: Vec<PeopleTruth>,
}

fn parse(
    path: &Path,
    bytes: &[u8],
    keep_people: bool,
) -> Result<(Recording, Vec<PeopleTruth>), RecordError> {
    let invalid = |what: String| RecordError::Invalid {
        path: path.to_path_buf(),
        what,
    };
    if !bytes.starts_with(mcap::MAGIC) {
        return Err(invalid(
            "not an MCAP recording (the file does not start with the MCAP magic bytes)".into(),
        ));
    }
    // A corrupt length field must not make the reader allocate what it says: no record or
    // decompressed chunk is larger than this in any recording scanfuse or Foxglove writes.
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_end_magic(true)
            .with_validate_chunk_crcs(true)
            .with_record_length_limit(MAX_RECORD_BYTES),
    );
    let mut rest = bytes;
    let mut state = Parse {
        keep_people,
        ..Parse::default()
    };
    let mut damage = None;
    let mut saw_data_end = false;
    while let Some(event) = reader.next_event() {
        let record = match event {
            Ok(LinearReadEvent::ReadRequest(need)) => {
                let len = need.min(rest.len());
                reader.insert(len).copy_from_slice(&rest[..len]);
                reader.notify_read(len);
                rest = &rest[len..];
                continue;
            }
            Ok(LinearReadEvent::Record { data, opcode }) => mcap::read::parse_record(opcode, data),
            Err(e) => Err(e),
        };
        let record = match record {
            Ok(record) => record,
            Err(e) => {
                damage = Some(invalid(format!(
                    "damaged after {} scans: {e}",
                    state.scans.values().map(Vec::len).sum::<usize>()
                )));
                break;
            }
        };
        if matches!(record, Record::DataEnd(_)) {
            saw_data_end = true;
            break;
        }
        if let Err(what) = state.take(record) {
            // A bad message or record: note the first, keep reading the rest.
            damage.get_or_insert_with(|| invalid(what));
        }
    }
    if damage.is_none() && !saw_data_end {
        damage = Some(invalid(
            "the file ends before its data-end record: it is truncated (an interrupted recording?)"
                .into(),
        ));
    }
    let people = std::mem::take(&mut state.people);
    Ok((state.finish(path, damage), people))
}

impl Parse {
    fn take(&mut self, record: Record<'_>) -> Result<(), String> {
        match record {
            Record::Schema { header, .. } => {
                self.schemas
                    .insert(header.id, (header.name, header.encoding));
            }
            Record::Channel(channel) => {
                if self.channels.contains_key(&channel.id) {
                    return Ok(()); // repeated in a summary or a later chunk
                }
                let schema = self
                    .schemas
                    .get(&channel.schema_id)
                    .map(|(name, _)| name.clone())
                    .unwrap_or_default();
                let kind = self.classify(&channel.topic, &schema, &channel.message_encoding);
                let listed = SkippedChannel {
                    topic: channel.topic.clone(),
                    schema,
                    encoding: channel.message_encoding.clone(),
                    messages: 0,
                };
                match kind {
                    Kind::Skipped(_) => self.skipped.push(listed),
                    Kind::Truth(_) => self.truth.push(listed),
                    _ => {}
                }
                self.channels.insert(
                    channel.id,
                    Channel {
                        topic: channel.topic,
                        kind,
                    },
                );
            }
            Record::Message { header, data } => self.message(&header, data)?,
            Record::Metadata(meta) if meta.name == SENSOR_RECORD => {
                let sensor = sensor_from_map(&meta.metadata)
                    .map_err(|e| format!("bad {SENSOR_RECORD} record: {e}"))?;
                if self.sensors.iter().any(|s| s.id == sensor.id) {
                    return Err(format!("two {SENSOR_RECORD} records for {}", sensor.id));
                }
                self.sensors.push(sensor);
            }
            Record::Metadata(meta) if meta.name == MOVE_RECORD => {
                let moved = move_from_map(&meta.metadata)
                    .map_err(|e| format!("bad {MOVE_RECORD} record: {e}"))?;
                self.moves.push(moved);
            }
            _ => {}
        }
        Ok(())
    }

    fn classify(&mut self, topic: &str, schema: &str, encoding: &str) -> Kind {
        if topic.starts_with(TRUTH_PREFIX) {
            return Kind::Truth(self.truth.len());
        }
        if schema == laserscan::SCHEMA_NAME && (encoding == "protobuf" || encoding == "json") {
            let sensor_id = sensor_id_of(topic, "scan");
            self.channel_order.push(sensor_id.clone());
            return Kind::Laser {
                sensor_id,
                json: encoding == "json",
            };
        }
        if encoding == SCIP_ENCODING {
            return Kind::Scip {
                sensor_id: sensor_id_of(topic, "scip"),
            };
        }
        Kind::Skipped(self.skipped.len())
    }

    fn message(
        &mut self,
        header: &mcap::records::MessageHeader,
        data: Cow<'_, [u8]>,
    ) -> Result<(), String> {
        let Some(channel) = self.channels.get(&header.channel_id) else {
            return Err(format!(
                "a message refers to channel {} which was never declared",
                header.channel_id
            ));
        };
        match &channel.kind {
            Kind::Laser { sensor_id, json } => {
                let scan = decode_scan(&data, *json, header.log_time)
                    .map_err(|e| format!("{}: message {}: {e}", channel.topic, header.sequence))?;
                self.scans.entry(sensor_id.clone()).or_default().push(scan);
            }
            Kind::Scip { sensor_id } => {
                *self.scip_messages.entry(sensor_id.clone()).or_default() += 1;
            }
            Kind::Skipped(index) => {
                if let Some(skipped) = self.skipped.get_mut(*index) {
                    skipped.messages += 1;
                }
            }
            Kind::Truth(index) => {
                if let Some(truth) = self.truth.get_mut(*index) {
                    truth.messages += 1;
                }
                if self.keep_people && channel.topic == PEOPLE_TRUTH_TOPIC {
                    let people: PeopleTruth = serde_json::from_slice(&data).map_err(|e| {
                        format!(
                            "{}: message {}: not the people's truth JSON: {e}",
                            channel.topic, header.sequence
                        )
                    })?;
                    self.people.push(people);
                }
            }
        }
        Ok(())
    }

    fn finish(mut self, path: &Path, damage: Option<RecordError>) -> Recording {
        // Laser channels without a scanfuse.sensor record (other writers) still get a sensor.
        for id in &self.channel_order {
            if !self.sensors.iter().any(|s| &s.id == id) {
                self.sensors.push(SensorInfo::new(id.clone(), ""));
            }
        }
        Recording {
            path: path.to_path_buf(),
            sensors: self.sensors,
            scans: self.scans,
            scip_messages: self.scip_messages,
            moves: self.moves,
            skipped: self.skipped,
            truth: self.truth,
            damage,
        }
    }
}

/// `/<id>/scan` → `id`; any other topic → the topic without slashes at its ends, inner
/// slashes turned into `_` (so `/front/laser` → `front_laser`).
fn sensor_id_of(topic: &str, leaf: &str) -> String {
    let trimmed = topic.trim_matches('/');
    if let Some(id) = trimmed.strip_suffix(leaf).and_then(|s| s.strip_suffix('/'))
        && !id.is_empty()
        && !id.contains('/')
    {
        return id.to_string();
    }
    trimmed.replace('/', "_")
}

/// The JSON form of `foxglove.LaserScan` (Foxglove's JSON encoding of its schemas).
#[derive(serde::Deserialize)]
struct JsonLaserScan {
    timestamp: Option<JsonTime>,
    #[serde(default)]
    start_angle: f64,
    #[serde(default)]
    end_angle: f64,
    #[serde(default)]
    ranges: Vec<Option<f64>>,
    #[serde(default)]
    intensities: Vec<Option<f64>>,
}

#[derive(serde::Deserialize)]
struct JsonTime {
    #[serde(default)]
    sec: i64,
    #[serde(default)]
    nsec: i32,
}

fn decode_scan(data: &[u8], json: bool, log_time_ns: u64) -> Result<Scan, String> {
    let message = if json {
        let j: JsonLaserScan =
            serde_json::from_slice(data).map_err(|e| format!("not a JSON LaserScan: {e}"))?;
        let nan = |v: Option<f64>| v.unwrap_or(f64::NAN);
        LaserScan {
            timestamp: j.timestamp.map(|t| Timestamp {
                seconds: t.sec,
                nanos: t.nsec,
            }),
            frame_id: String::new(),
            pose: None,
            start_angle: j.start_angle,
            end_angle: j.end_angle,
            ranges: j.ranges.into_iter().map(nan).collect(),
            intensities: j.intensities.into_iter().map(nan).collect(),
        }
    } else {
        LaserScan::decode(data).map_err(|e| format!("not a protobuf LaserScan: {e}"))?
    };
    if !message.intensities.is_empty() && message.intensities.len() != message.ranges.len() {
        return Err(format!(
            "{} intensities for {} ranges",
            message.intensities.len(),
            message.ranges.len()
        ));
    }
    if !message.start_angle.is_finite() || !message.end_angle.is_finite() {
        return Err("start_angle or end_angle is not finite".into());
    }
    let stamp_ns = message
        .timestamp
        .and_then(Timestamp::to_ns)
        .filter(|ns| *ns > 0)
        .unwrap_or(log_time_ns);
    Ok(Scan {
        stamp_ns,
        sensor_stamp_ms: None,
        start_angle_rad: message.start_angle,
        end_angle_rad: message.end_angle,
        ranges_m: message.ranges.iter().map(|r| *r as f32).collect(),
        intensities: message.intensities.iter().map(|i| *i as f32).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::sensor_id_of;

    #[test]
    fn sensor_ids_come_from_topics() {
        assert_eq!(sensor_id_of("/door/scan", "scan"), "door");
        assert_eq!(sensor_id_of("/scan", "scan"), "scan");
        assert_eq!(sensor_id_of("/front/laser", "scan"), "front_laser");
        assert_eq!(sensor_id_of("/a/b/scan", "scan"), "a_b_scan");
        assert_eq!(sensor_id_of("/door/scip", "scip"), "door");
    }
}
