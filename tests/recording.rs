//! Recordings: write → read round trip, files from another writer, damaged files.

use std::path::Path;

use scanfuse::record::{self, RecordingWriter, partial_path};
use scanfuse::scan::{MoveTruth, Scan, ScanGeometry, SensorInfo, TruthPose};

fn sensor(id: &str, geometry: ScanGeometry) -> SensorInfo {
    let mut s = SensorInfo::new(id, "UTM-30LX-EW");
    s.connect = "sim:test".into();
    s.geometry = Some(geometry);
    s.fields = geometry.to_fields();
    s.fields.insert("SERI".into(), format!("SIM-{id}"));
    s.height_m = Some(1.0);
    s.pitch_deg = Some(0.0);
    s.truth = Some(TruthPose {
        x_m: 1.0,
        y_m: 2.0,
        yaw_deg: 30.0,
    });
    s
}

fn scan(geometry: &ScanGeometry, k: u64, with_intensities: bool) -> Scan {
    let n = geometry.step_count();
    Scan {
        stamp_ns: 1_767_225_600_000_000_000 + k * 25_000_000,
        sensor_stamp_ms: None,
        start_angle_rad: geometry.angle_of_step_rad(geometry.amin),
        end_angle_rad: geometry.angle_of_step_rad(geometry.amax),
        ranges_m: (0..n)
            .map(|i| {
                if i % 17 == 0 {
                    0.0
                } else {
                    (1000 + i as u64 + k) as f32 / 1000.0
                }
            })
            .collect(),
        intensities: if with_intensities {
            (0..n).map(|i| (i % 4000) as f32).collect()
        } else {
            vec![]
        },
    }
}

/// Writes two sensors with `scans` scans each, a move, and raw SCIP for one of them.
fn write_sample(path: &Path, scans: u64) -> (Vec<SensorInfo>, Vec<Vec<Scan>>, MoveTruth) {
    let sensors = vec![
        sensor("door", ScanGeometry::UTM_30LX_EW),
        sensor("hall-2", ScanGeometry::UXM_30LX_E),
    ];
    let moved = MoveTruth {
        sensor_id: "door".into(),
        at_ns: 1_767_225_601_000_000_000,
        pose: TruthPose {
            x_m: 1.5,
            y_m: 2.0,
            yaw_deg: 40.0,
        },
    };
    let mut w = RecordingWriter::create(path).unwrap();
    for s in &sensors {
        w.add_sensor(s).unwrap();
    }
    w.add_move(&moved).unwrap();
    let mut written = vec![vec![], vec![]];
    for k in 0..scans {
        for (i, s) in sensors.iter().enumerate() {
            let sc = scan(s.geometry.as_ref().unwrap(), k, i == 0);
            w.write_scan(&s.id, &sc).unwrap();
            written[i].push(sc);
        }
        w.write_scip("door", 1_767_225_600_000_000_000 + k, b"MD0000108001000\n")
            .unwrap();
    }
    assert!(partial_path(path).exists() && !path.exists());
    w.finish().unwrap();
    assert!(path.exists() && !partial_path(path).exists());
    (sensors, written, moved)
}

#[test]
fn what_is_written_reads_back_the_same() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rt.mcap");
    let (sensors, written, moved) = write_sample(&path, 30);
    let rec = record::read(&path).unwrap();
    assert_eq!(rec.sensors, sensors);
    assert_eq!(rec.moves, vec![moved]);
    assert_eq!(rec.scip_messages.get("door"), Some(&30));
    assert!(rec.skipped.is_empty());
    for (s, scans) in sensors.iter().zip(&written) {
        let read = rec.scans_of(&s.id);
        assert_eq!(read.len(), scans.len());
        for (a, b) in read.iter().zip(scans) {
            assert_eq!(a.stamp_ns, b.stamp_ns);
            assert_eq!(
                (a.start_angle_rad, a.end_angle_rad),
                (b.start_angle_rad, b.end_angle_rad)
            );
            assert_eq!(a.intensities, b.intensities);
            let mm = |v: &[f32]| {
                v.iter()
                    .map(|r| (r * 1000.0).round() as i64)
                    .collect::<Vec<_>>()
            };
            assert_eq!(mm(&a.ranges_m), mm(&b.ranges_m));
        }
    }
}

#[test]
fn ranges_are_stored_as_the_nearest_double_to_the_millimetre() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("mm.mcap");
    write_sample(&path, 1);
    let bytes = std::fs::read(&path).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let stream = mcap::MessageStream::new(&bytes).unwrap();
    let first = stream
        .map(|m| m.unwrap())
        .find(|m| m.channel.topic == "/door/scan")
        .unwrap();
    use prost::Message;
    let msg = record::laserscan::LaserScan::decode(first.data.as_ref()).unwrap();
    assert_eq!(msg.ranges[1], 1.001);
    assert_eq!(msg.frame_id, "door");
    assert_eq!(summary.channels.len(), 3);
}

#[test]
fn a_recording_from_the_foxglove_sdk_reads() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/external/foxglove_sdk.mcap");
    let rec = record::read(&path).unwrap();
    let ids: Vec<&str> = rec.sensors.iter().map(|s| s.id.as_str()).collect();
    assert_eq!(ids, ["door", "front_laser"]);
    let door = rec.sensor("door").unwrap();
    assert_eq!(door.geometry, Some(ScanGeometry::UTM_30LX_EW));
    assert_eq!(door.connect, "tcp://192.168.0.10:10940");
    let scans = rec.scans_of("door");
    assert_eq!(scans.len(), 5);
    assert_eq!(scans[1].stamp_ns, 1_767_225_600_025_000_000);
    assert_eq!(scans[0].ranges_m.len(), 1081);
    assert_eq!(scans[0].ranges_m[10], 1.01);
    assert_eq!(scans[4].intensities[1080], 2080.0);
    let front = rec.scans_of("front_laser");
    assert_eq!(front.len(), 5);
    assert!(front[0].intensities.is_empty());
    assert!((front[0].start_angle_rad + std::f64::consts::FRAC_PI_2).abs() < 1e-12);
    assert_eq!(rec.sensor("front_laser").unwrap().geometry, None);
    assert_eq!(rec.skipped.len(), 1);
    assert_eq!(rec.skipped[0].topic, "/rosout");
    assert_eq!(rec.skipped[0].schema, "foxglove.Log");
    assert_eq!(rec.skipped[0].messages, 5);
}

#[test]
fn a_truncated_file_keeps_every_scan_before_the_cut_and_says_what_is_wrong() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("full.mcap");
    write_sample(&path, 200);
    let bytes = std::fs::read(&path).unwrap();
    let total = record::read(&path).unwrap().scans_of("door").len();
    let cut = dir.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();

    let err = record::read(&cut).unwrap_err().to_string();
    assert!(err.contains("cut.mcap"), "{err}");
    let rec = record::read_lenient(&cut).unwrap();
    let kept = rec.scans_of("door").len();
    assert!(kept > 0 && kept < total, "kept {kept} of {total}");
    let damage = rec.damage.as_ref().unwrap().to_string();
    assert!(damage.contains("cut.mcap"), "{damage}");
    // The kept scans are exactly the first ones written.
    let full = record::read(&path).unwrap();
    assert_eq!(rec.scans_of("door"), &full.scans_of("door")[..kept]);
}

#[test]
fn a_corrupt_chunk_is_reported_and_earlier_scans_kept() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("full.mcap");
    write_sample(&path, 200);
    let mut bytes = std::fs::read(&path).unwrap();
    let mid = bytes.len() * 3 / 4;
    for b in &mut bytes[mid..mid + 64] {
        *b ^= 0x5a;
    }
    let bad = dir.path().join("bad.mcap");
    std::fs::write(&bad, &bytes).unwrap();
    let rec = record::read_lenient(&bad).unwrap();
    assert!(rec.damage.is_some());
    assert!(!rec.scans_of("door").is_empty());
    assert!(record::read(&bad).is_err());
}

#[test]
fn a_file_that_is_not_mcap_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("notes.txt");
    std::fs::write(&path, "hello").unwrap();
    let err = record::read_lenient(&path).unwrap_err().to_string();
    assert!(
        err.contains("notes.txt") && err.contains("not an MCAP"),
        "{err}"
    );
    let missing = record::read(&dir.path().join("nope.mcap"))
        .unwrap_err()
        .to_string();
    assert!(missing.contains("nope.mcap"), "{missing}");
}

#[test]
fn bad_sensor_ids_and_unknown_sensors_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let mut w = RecordingWriter::create(&dir.path().join("x.mcap")).unwrap();
    let err = w.add_sensor(&SensorInfo::new("a/b", "")).unwrap_err();
    assert!(err.to_string().contains("a/b"));
    let geometry = ScanGeometry::UTM_30LX_EW;
    let err = w
        .write_scan("ghost", &scan(&geometry, 0, false))
        .unwrap_err();
    assert!(err.to_string().contains("ghost"));
}

mod damage {
    use super::*;
    use proptest::prelude::*;

    fn sample() -> &'static [u8] {
        static BYTES: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
        BYTES.get_or_init(|| {
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("s.mcap");
            write_sample(&path, 40);
            std::fs::read(&path).unwrap()
        })
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(300))]

        /// Any cut, any flipped bytes: the reader returns, never panics, and what it returns
        /// is either the whole recording or damage with the file named.
        #[test]
        fn damaged_files_never_panic_the_reader(
            cut in 0usize..=100,
            flips in proptest::collection::vec((0usize..100_000, any::<u8>()), 0..8),
        ) {
            let mut bytes = sample().to_vec();
            let len = bytes.len() * cut / 100;
            bytes.truncate(len.max(8));
            for (at, x) in flips {
                let n = bytes.len();
                bytes[at % n] ^= x | 1;
            }
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("d.mcap");
            std::fs::write(&path, &bytes).unwrap();
            match record::read_lenient(&path) {
                Ok(rec) => {
                    if let Some(d) = &rec.damage {
                        prop_assert!(d.to_string().contains("d.mcap"));
                    }
                    for scans in rec.scans.values() {
                        for s in scans {
                            prop_assert!(s.intensities.is_empty() || s.intensities.len() == s.ranges_m.len());
                        }
                    }
                }
                Err(e) => prop_assert!(e.to_string().contains("d.mcap")),
            }
        }
    }
}
