//! `poses.toml` on disk, and the atomic write every state file goes through.

use std::io::Write;
use std::path::Path;
use std::time::{Duration, UNIX_EPOCH};

use scanfuse::daemon::protocol::{PoseSource, SensorPose};
use scanfuse::daemon::state::{
    POSES_FILE, PosesFile, SavedPose, StateError, write_atomic, write_atomic_with,
};

fn poses(yaw_deg: f64) -> PosesFile {
    let mut a = SensorPose::unregistered("a", "");
    a.registered = true;
    a.reason = None;
    a.x_m = Some(0.0);
    a.y_m = Some(0.0);
    a.yaw_deg = Some(0.0);
    let mut b = a.clone();
    b.id = "b".into();
    b.x_m = Some(2.5);
    b.y_m = Some(-0.75);
    b.yaw_deg = Some(yaw_deg);
    b.sigma_x_m = Some(0.01);
    let t = UNIX_EPOCH + Duration::from_secs(1_800_000_000);
    PosesFile {
        anchor: "a".into(),
        sensors: vec![
            SavedPose::from_pose(&a, PoseSource::Registered, t),
            SavedPose::from_pose(&b, PoseSource::Surveyed, t),
        ],
        building_from_site: None,
    }
}

/// Files in `dir` other than `keep`: temp files must not be left behind.
fn others(dir: &Path, keep: &str) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n != keep)
        .collect()
}

#[test]
fn poses_round_trip_through_the_state_dir() {
    let dir = tempfile::tempdir().unwrap();
    assert!(PosesFile::load(dir.path()).unwrap().is_none());
    let written = poses(45.0);
    let path = written.save(dir.path()).unwrap();
    assert_eq!(path, dir.path().join(POSES_FILE));
    assert_eq!(PosesFile::load(dir.path()).unwrap(), Some(written));
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(
        text.contains("updated = \"2027-01-15T08:00:00Z\""),
        "{text}"
    );
    assert!(others(dir.path(), POSES_FILE).is_empty());
    // Saving again replaces it.
    poses(46.0).save(dir.path()).unwrap();
    assert_eq!(
        PosesFile::load(dir.path()).unwrap().unwrap().sensors[1].yaw_deg,
        Some(46.0)
    );
}

#[test]
fn an_interrupted_write_leaves_the_old_file_intact() {
    let dir = tempfile::tempdir().unwrap();
    let old = poses(45.0);
    let path = old.save(dir.path()).unwrap();
    let new_text = poses(90.0).to_toml().unwrap();
    // The write fails halfway, as a full disk would make it.
    let result = write_atomic_with(&path, |file| {
        file.write_all(&new_text.as_bytes()[..new_text.len() / 2])?;
        Err(std::io::Error::other("no space left on device (simulated)"))
    });
    match result {
        Err(e @ StateError::Write { .. }) => {
            assert!(e.to_string().contains("no space left"), "{e}")
        }
        other => panic!("expected a write error, got {other:?}"),
    }
    assert_eq!(PosesFile::load(dir.path()).unwrap(), Some(old));
    assert!(
        others(dir.path(), POSES_FILE).is_empty(),
        "the temp file is removed"
    );
}

#[test]
fn a_write_that_cannot_replace_the_target_changes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    // The target is a non-empty directory: the rename fails after the temp file was written.
    let target = dir.path().join("map.pgm");
    std::fs::create_dir(&target).unwrap();
    std::fs::write(target.join("keep"), b"x").unwrap();
    assert!(write_atomic(&target, b"P5 1 1 255\n\0").is_err());
    assert!(target.join("keep").exists());
    assert!(
        others(dir.path(), "map.pgm").is_empty(),
        "the temp file is removed"
    );
    // A missing folder is an error naming the path, not a panic.
    let err = write_atomic(&dir.path().join("no/such/dir/poses.toml"), b"x").unwrap_err();
    assert!(err.to_string().contains("no/such/dir/poses.toml"), "{err}");
}

#[test]
fn write_atomic_writes_exactly_the_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("map.yaml");
    write_atomic(&path, b"image: map.pgm\n").unwrap();
    write_atomic(&path, b"image: map.pgm\nresolution: 0.05\n").unwrap();
    assert_eq!(
        std::fs::read(&path).unwrap(),
        b"image: map.pgm\nresolution: 0.05\n"
    );
    assert!(others(dir.path(), "map.yaml").is_empty());
}

/// `SavedPose` stays a separate struct from the socket's `SensorPose` (the file refuses
/// unknown keys, which serde's `flatten` would switch off), so
/// this pins the two vocabularies together: every socket field but `age_s` is in the file,
/// under the same name and with the same value, plus `updated`.
#[test]
fn the_file_and_the_socket_use_one_pose_vocabulary() {
    let mut pose = SensorPose::unregistered("b", "a caveat");
    pose.registered = true;
    pose.x_m = Some(1.5);
    pose.y_m = Some(-2.0);
    pose.yaw_deg = Some(30.0);
    pose.z_m = Some(1.1);
    pose.pitch_deg = Some(-2.0);
    pose.sigma_x_m = Some(0.01);
    pose.sigma_y_m = Some(0.02);
    pose.sigma_yaw_deg = Some(0.1);
    pose.age_s = Some(3.0);
    pose.source = Some(PoseSource::ReRegistered);
    let socket = serde_json::to_value(&pose).unwrap();
    let saved = SavedPose::from_pose(&pose, PoseSource::ReRegistered, UNIX_EPOCH);
    let file = serde_json::to_value(&saved).unwrap();
    let (socket, file) = (socket.as_object().unwrap(), file.as_object().unwrap());
    for (key, value) in socket {
        if key == "age_s" {
            assert!(!file.contains_key(key), "age_s is the socket's alone");
        } else {
            assert_eq!(file.get(key), Some(value), "{key}");
        }
    }
    let extra: Vec<&String> = file.keys().filter(|k| !socket.contains_key(*k)).collect();
    assert_eq!(extra, ["updated"]);
    // And back: the socket form of a saved pose says where it came from.
    let back = saved.to_pose(UNIX_EPOCH + Duration::from_secs(5));
    assert_eq!(back.source, Some(PoseSource::Saved));
    assert_eq!(back.age_s, Some(5.0));
    assert_eq!(
        (back.x_m, back.sigma_yaw_deg),
        (pose.x_m, pose.sigma_yaw_deg)
    );
}

/// A sensor without a pose was obtained by nothing: `poses.toml` writes no `source` beside
/// `registered = false`, and the socket form read back from the file has none either.
#[test]
fn an_unregistered_sensor_is_saved_without_a_source() {
    let dir = tempfile::tempdir().unwrap();
    let mut file = poses(45.0);
    file.sensors.push(SavedPose::from_pose(
        &SensorPose::unregistered("c", "it shares no usable view with any placed sensor"),
        PoseSource::Registered,
        UNIX_EPOCH + Duration::from_secs(1_800_000_000),
    ));
    let path = file.save(dir.path()).unwrap();
    let text = std::fs::read_to_string(&path).unwrap();
    let c = text
        .split("[[sensor]]")
        .find(|t| t.contains("id = \"c\""))
        .expect("c's table");
    assert!(c.contains("registered = false"), "{c}");
    assert!(!c.contains("source"), "{c}");
    // The registered ones keep theirs.
    assert_eq!(text.matches("source = ").count(), 2, "{text}");
    let back = PosesFile::load(dir.path()).unwrap().unwrap();
    assert_eq!(back, file);
    let socket = serde_json::to_string(&back.sensors[2].to_pose(UNIX_EPOCH)).unwrap();
    assert!(
        !socket.contains("source") && !socket.contains("null"),
        "{socket}"
    );
}
