//! The `foxglove.LaserScan` protobuf message, as the Foxglove SDK defines and writes it.
//!
//! Hand-derived with prost (no protoc at build time). The schema bytes are the
//! `FileDescriptorSet` the Foxglove SDK itself puts in the MCAP schema record, so Foxglove and
//! the Python `mcap` reader decode our files with their own protobuf decoders.

/// Schema name in the MCAP schema record.
pub const SCHEMA_NAME: &str = "foxglove.LaserScan";
/// Schema and message encoding.
pub const ENCODING: &str = "protobuf";
/// `FileDescriptorSet` of `foxglove/LaserScan.proto` and its imports, from the Foxglove SDK.
pub const SCHEMA_DESCRIPTOR: &[u8] = include_bytes!("foxglove_laserscan.fds");

/// `google.protobuf.Timestamp`.
#[derive(Clone, Copy, PartialEq, prost::Message)]
pub struct Timestamp {
    #[prost(int64, tag = "1")]
    pub seconds: i64,
    #[prost(int32, tag = "2")]
    pub nanos: i32,
}

/// `foxglove.Vector3`.
#[derive(Clone, Copy, PartialEq, prost::Message)]
pub struct Vector3 {
    #[prost(double, tag = "1")]
    pub x: f64,
    #[prost(double, tag = "2")]
    pub y: f64,
    #[prost(double, tag = "3")]
    pub z: f64,
}

/// `foxglove.Quaternion`.
#[derive(Clone, Copy, PartialEq, prost::Message)]
pub struct Quaternion {
    #[prost(double, tag = "1")]
    pub x: f64,
    #[prost(double, tag = "2")]
    pub y: f64,
    #[prost(double, tag = "3")]
    pub z: f64,
    #[prost(double, tag = "4")]
    pub w: f64,
}

/// `foxglove.Pose`.
#[derive(Clone, Copy, PartialEq, prost::Message)]
pub struct Pose {
    #[prost(message, optional, tag = "1")]
    pub position: Option<Vector3>,
    #[prost(message, optional, tag = "2")]
    pub orientation: Option<Quaternion>,
}

impl Pose {
    /// The scan's origin is its frame's origin.
    pub fn identity() -> Self {
        Pose {
            position: Some(Vector3::default()),
            orientation: Some(Quaternion {
                w: 1.0,
                ..Quaternion::default()
            }),
        }
    }
}

/// `foxglove.LaserScan`.
#[derive(Clone, PartialEq, prost::Message)]
pub struct LaserScan {
    #[prost(message, optional, tag = "1")]
    pub timestamp: Option<Timestamp>,
    #[prost(string, tag = "2")]
    pub frame_id: String,
    #[prost(message, optional, tag = "3")]
    pub pose: Option<Pose>,
    #[prost(double, tag = "4")]
    pub start_angle: f64,
    #[prost(double, tag = "5")]
    pub end_angle: f64,
    #[prost(double, repeated, tag = "6")]
    pub ranges: Vec<f64>,
    #[prost(double, repeated, tag = "7")]
    pub intensities: Vec<f64>,
}

impl Timestamp {
    /// Nanoseconds since the epoch, or `None` when negative or out of range.
    pub fn to_ns(self) -> Option<u64> {
        let seconds = u64::try_from(self.seconds).ok()?;
        let nanos = u64::try_from(self.nanos)
            .ok()
            .filter(|n| *n < 1_000_000_000)?;
        seconds.checked_mul(1_000_000_000)?.checked_add(nanos)
    }

    pub fn from_ns(ns: u64) -> Self {
        Timestamp {
            seconds: (ns / 1_000_000_000) as i64,
            nanos: (ns % 1_000_000_000) as i32,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use prost::Message;

    /// Bytes the Python foxglove-sdk 0.30 wrote for a 3-range scan (see fixtures/external/).
    const SDK_BYTES: &str = "0a040801100512016121000000000000f0bf29000000000000f03f3218000000000000f03f000000000000004000000000000008403a18000000000000244000000000000034400000000000003e40";

    fn hex(s: &str) -> Vec<u8> {
        (0..s.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap())
            .collect()
    }

    #[test]
    fn decodes_what_the_foxglove_sdk_writes_and_encodes_it_back_identically() {
        let bytes = hex(SDK_BYTES);
        let scan = LaserScan::decode(bytes.as_slice()).unwrap();
        assert_eq!(scan.frame_id, "a");
        assert_eq!(
            scan.timestamp.and_then(Timestamp::to_ns),
            Some(1_000_000_005)
        );
        assert_eq!((scan.start_angle, scan.end_angle), (-1.0, 1.0));
        assert_eq!(scan.ranges, vec![1.0, 2.0, 3.0]);
        assert_eq!(scan.intensities, vec![10.0, 20.0, 30.0]);
        assert_eq!(scan.encode_to_vec(), bytes);
    }

    #[test]
    fn schema_descriptor_names_laserscan() {
        let text = String::from_utf8_lossy(SCHEMA_DESCRIPTOR);
        assert!(text.contains("foxglove/LaserScan.proto"));
        assert!(text.contains("google/protobuf/timestamp.proto"));
    }

    #[test]
    fn negative_or_overflowing_timestamps_are_rejected() {
        assert_eq!(
            Timestamp {
                seconds: -1,
                nanos: 0
            }
            .to_ns(),
            None
        );
        assert_eq!(
            Timestamp {
                seconds: 1,
                nanos: 1_000_000_000
            }
            .to_ns(),
            None
        );
        assert_eq!(
            Timestamp::from_ns(1_500_000_001).to_ns(),
            Some(1_500_000_001)
        );
    }
}
