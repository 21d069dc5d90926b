//! A scanfuse recording opens in the official Python `mcap` reader with its protobuf decoder.

use crate::common;

use std::process::Command;

use scanfuse::record::RecordingWriter;
use scanfuse::scan::{Scan, ScanGeometry, SensorInfo, TruthPose};

#[test]
fn python_mcap_reader_decodes_our_laserscans_and_metadata() {
    let Some(python) =
        common::test_python("python_mcap_reader_decodes_our_laserscans_and_metadata")
    else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("interop.mcap");
    let g = ScanGeometry::UTM_30LX_EW;
    let mut sensor = SensorInfo::new("door", "UTM-30LX-EW");
    sensor.geometry = Some(g);
    sensor.fields = g.to_fields();
    sensor.truth = Some(TruthPose {
        x_m: 1.0,
        y_m: -2.0,
        yaw_deg: 45.0,
    });
    let mut w = RecordingWriter::create(&path).unwrap();
    w.add_sensor(&sensor).unwrap();
    for k in 0..3u64 {
        let scan = Scan {
            stamp_ns: 1_767_225_600_000_000_000 + k * 25_000_000,
            sensor_stamp_ms: None,
            start_angle_rad: g.angle_of_step_rad(0),
            end_angle_rad: g.angle_of_step_rad(1080),
            ranges_m: (0..1081).map(|i| 1.0 + i as f32 / 1000.0).collect(),
            intensities: (0..1081).map(|i| i as f32).collect(),
        };
        w.write_scan("door", &scan).unwrap();
    }
    w.finish().unwrap();

    let out = common::succeeded(
        Command::new(&python)
            .arg(common::repo().join("tests/python/read_recording.py"))
            .arg(&path),
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let t = &v["topics"]["/door/scan"];
    assert_eq!(t["count"], 3);
    assert_eq!(t["schema"], "foxglove.LaserScan");
    assert_eq!(t["frame_id"], "door");
    assert_eq!(t["stamp_ns"], 1_767_225_600_000_000_000u64);
    assert_eq!(t["ranges"], 1081);
    assert_eq!(t["intensities"], 1081);
    assert_eq!(t["first_ranges"], serde_json::json!([1.0, 1.001, 1.002]));
    assert!((t["start_angle"].as_f64().unwrap() + 0.75 * std::f64::consts::PI).abs() < 1e-12);
    let meta = &v["metadata"][0];
    assert_eq!(meta["name"], "scanfuse.sensor");
    assert_eq!(meta["metadata"]["truth_yaw_deg"], "45");
    assert_eq!(meta["metadata"]["AFRT"], "540");
}
