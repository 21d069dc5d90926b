//! What the daemon keeps on disk between runs: `poses.toml`, and the atomic write every state
//! file goes through (so a crash or SIGTERM mid-write leaves the old file or the new, never a
//! torn one).

use std::collections::BTreeSet;
use std::fs::File;
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::SystemTime;

use serde::{Deserialize, Serialize};

use super::config::Config;
use super::protocol::{PoseSource, SensorPose, pose_vocabulary};

/// The state file name for poses, in the state directory.
pub const POSES_FILE: &str = "poses.toml";

/// A state file could not be written or read back.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StateError {
    #[error("cannot write {}: {source}", path.display())]
    Write { path: PathBuf, source: io::Error },
    #[error("cannot encode the poses as TOML: {0}")]
    Encode(String),
    #[error("cannot read {}: {source}", path.display())]
    Read { path: PathBuf, source: io::Error },
    #[error("{} is not a valid poses file: {message}", path.display())]
    Invalid { path: PathBuf, message: String },
    #[error("{} does not match the config: {}; the sensors will be registered afresh", path.display(), problems.join("; "))]
    Mismatch {
        path: PathBuf,
        problems: Vec<String>,
    },
}

/// Writes `bytes` to `path` atomically: see [`write_atomic_with`].
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), StateError> {
    write_atomic_with(path, |file| file.write_all(bytes))
}

/// Writes a file atomically: `write` fills a temporary file in the same folder, which is
/// fsynced and renamed over `path`, then the folder is fsynced so the rename itself survives a
/// power cut. If anything fails the temporary file is removed and `path` keeps its old content.
pub fn write_atomic_with(
    path: &Path,
    write: impl FnOnce(&mut File) -> io::Result<()>,
) -> Result<(), StateError> {
    let fail = |source| StateError::Write {
        path: path.to_path_buf(),
        source,
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let Some(name) = path.file_name() else {
        return Err(fail(io::Error::new(
            io::ErrorKind::InvalidInput,
            "the path names no file",
        )));
    };
    // Hidden, and unique per process and call, so concurrent writers never share a temp file.
    static CALLS: AtomicU64 = AtomicU64::new(0);
    let unique = CALLS.fetch_add(1, Ordering::Relaxed);
    let tmp = dir.join(format!(
        ".{}.tmp-{}-{unique}",
        name.to_string_lossy(),
        std::process::id()
    ));
    let result = (|| {
        let mut file = File::options().write(true).create_new(true).open(&tmp)?;
        write(&mut file)?;
        file.sync_all()?;
        drop(file);
        std::fs::rename(&tmp, path)?;
        File::open(dir)?.sync_all()
    })();
    if let Err(e) = result {
        let _ = std::fs::remove_file(&tmp);
        return Err(fail(e));
    }
    Ok(())
}

/// The contents of `poses.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PosesFile {
    /// The sensor whose frame is the site frame.
    pub anchor: String,
    #[serde(rename = "sensor", default)]
    pub sensors: Vec<SavedPose>,
    /// Where the site frame lies in the building drawing's, when aligned (`scanfuse align
    /// --save`); kept beside the poses, never folded into them. Absent in older files.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub building_from_site: Option<crate::drawing::BuildingFromSite>,
}

/// Sets `building_from_site` in `dir`'s `poses.toml` (a file with no poses yet when there is
/// none, or one for another anchor), keeping its poses: the next save of the poses and map
/// files (`pipeline_fuse::save_files`) then writes them in building coordinates. `None`
/// forgets it (the drawing changed); without a file of this anchor there is nothing to forget.
pub fn keep_building_from_site(
    dir: &Path,
    anchor: &str,
    building: Option<crate::drawing::BuildingFromSite>,
) -> Result<(), StateError> {
    let mut file = match (PosesFile::load(dir)?, &building) {
        (Some(f), _) if f.anchor == anchor => f,
        // Nothing of this site's to forget.
        (_, None) => return Ok(()),
        _ => PosesFile {
            anchor: anchor.to_string(),
            sensors: Vec::new(),
            building_from_site: None,
        },
    };
    file.building_from_site = building;
    std::fs::create_dir_all(dir).map_err(|source| StateError::Write {
        path: dir.to_path_buf(),
        source,
    })?;
    file.save(dir).map(|_| ())
}

pose_vocabulary! {
    /// One `[[sensor]]` of `poses.toml`: the register/socket pose vocabulary plus `source` and
    /// `updated`. An unregistered sensor has a `reason` and no pose fields, and no `source`.
    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct SavedPose {
        /// How the pose was obtained (never `saved`: a pose read back keeps its origin);
        /// present exactly when the sensor is registered.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pub source: Option<PoseSource>,
        /// When the pose was obtained, RFC 3339 UTC.
        pub updated: String,
    }
}

impl SavedPose {
    /// The file form of a socket pose, stamped `updated`. `source` is kept for a registered
    /// pose only: a sensor without a pose was obtained by nothing.
    pub fn from_pose(pose: &SensorPose, source: PoseSource, updated: SystemTime) -> SavedPose {
        SavedPose {
            id: pose.id.clone(),
            registered: pose.registered,
            x_m: pose.x_m,
            y_m: pose.y_m,
            yaw_deg: pose.yaw_deg,
            z_m: pose.z_m,
            pitch_deg: pose.pitch_deg,
            sigma_x_m: pose.sigma_x_m,
            sigma_y_m: pose.sigma_y_m,
            sigma_yaw_deg: pose.sigma_yaw_deg,
            reason: pose.reason.clone(),
            source: pose.registered.then_some(source),
            updated: humantime::format_rfc3339_seconds(updated).to_string(),
        }
    }

    /// The socket form: `source` becomes `saved` (for a registered pose), `age_s` is counted
    /// from `updated` to `now`.
    pub fn to_pose(&self, now: SystemTime) -> SensorPose {
        let age_s = humantime::parse_rfc3339(&self.updated)
            .ok()
            .and_then(|t| now.duration_since(t).ok())
            .map(|d| d.as_secs_f64());
        SensorPose {
            id: self.id.clone(),
            registered: self.registered,
            x_m: self.x_m,
            y_m: self.y_m,
            yaw_deg: self.yaw_deg,
            z_m: self.z_m,
            pitch_deg: self.pitch_deg,
            sigma_x_m: self.sigma_x_m,
            sigma_y_m: self.sigma_y_m,
            sigma_yaw_deg: self.sigma_yaw_deg,
            reason: self.reason.clone(),
            age_s,
            source: self.registered.then_some(PoseSource::Saved),
            evidence: None,
            zone: None,
            stale: false,
        }
    }
}

impl PosesFile {
    /// The TOML text, as written to disk.
    pub fn to_toml(&self) -> Result<String, StateError> {
        let header = "# Written by scanfuse: where each sensor stands in the anchor's frame.\n\
                      # Replaced atomically; edit only while the daemon is stopped.\n";
        let body = toml::to_string(self).map_err(|e| StateError::Encode(e.to_string()))?;
        Ok(format!("{header}{body}"))
    }

    /// Writes `dir/poses.toml` atomically.
    pub fn save(&self, dir: &Path) -> Result<PathBuf, StateError> {
        let path = dir.join(POSES_FILE);
        write_atomic(&path, self.to_toml()?.as_bytes())?;
        Ok(path)
    }

    /// Parses and checks a poses file's text (no I/O; `path` is for messages).
    pub fn parse(text: &str, path: &Path) -> Result<PosesFile, StateError> {
        let invalid = |message: String| StateError::Invalid {
            path: path.to_path_buf(),
            message,
        };
        let mut file: PosesFile = toml::from_str(text).map_err(|e| {
            let line = e.span().map_or(0, |s| {
                text.as_bytes()
                    .get(..s.start)
                    .map_or(0, |b| b.iter().filter(|&&c| c == b'\n').count())
                    + 1
            });
            invalid(format!("line {line}: {}", e.message().trim()))
        })?;
        for s in file.sensors.iter_mut().filter(|s| !s.registered) {
            // Files written before `source` was left out for these said "registered".
            s.source = None;
        }
        let mut seen = BTreeSet::new();
        for s in &file.sensors {
            if !seen.insert(s.id.as_str()) {
                return Err(invalid(format!("sensor {:?} appears twice", s.id)));
            }
            let pose = [s.x_m, s.y_m, s.yaw_deg];
            if s.registered && pose.iter().any(|v| !v.is_some_and(f64::is_finite)) {
                return Err(invalid(format!(
                    "sensor {:?} is registered but lacks a finite x_m, y_m or yaw_deg",
                    s.id
                )));
            }
            if !s.registered && pose.iter().any(Option::is_some) {
                return Err(invalid(format!(
                    "sensor {:?} is not registered but has pose fields",
                    s.id
                )));
            }
            if s.registered && s.source.is_none() {
                return Err(invalid(format!(
                    "sensor {:?} is registered but has no source (registered, re-registered or surveyed)",
                    s.id
                )));
            }
            if s.source == Some(PoseSource::Saved) {
                return Err(invalid(format!(
                    "sensor {:?}: source must say how the pose was obtained (registered, re-registered or surveyed), not \"saved\"",
                    s.id
                )));
            }
            if humantime::parse_rfc3339(&s.updated).is_err() {
                return Err(invalid(format!(
                    "sensor {:?}: updated = {:?} is not an RFC 3339 UTC time like 2026-01-31T12:00:00Z",
                    s.id, s.updated
                )));
            }
        }
        if !seen.contains(file.anchor.as_str()) {
            return Err(invalid(format!(
                "the anchor {:?} has no [[sensor]] entry",
                file.anchor
            )));
        }
        Ok(file)
    }

    /// Reads `dir/poses.toml`; `Ok(None)` when there is none yet.
    pub fn load(dir: &Path) -> Result<Option<PosesFile>, StateError> {
        let path = dir.join(POSES_FILE);
        match std::fs::read_to_string(&path) {
            Ok(text) => PosesFile::parse(&text, &path).map(Some),
            Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(None),
            Err(source) => Err(StateError::Read { path, source }),
        }
    }

    /// Reads `poses.toml` from the config's state directory if it is there and fits the
    /// config. `Ok(None)`: nothing saved yet. `Err`: unreadable, invalid or for other sensors;
    /// the daemon logs it and registers afresh.
    pub fn load_matching(config: &Config) -> Result<Option<PosesFile>, StateError> {
        let dir = &config.site.state_dir;
        let Some(file) = PosesFile::load(dir)? else {
            return Ok(None);
        };
        file.matches(config, &dir.join(POSES_FILE))?;
        Ok(Some(file))
    }

    /// Checks that these poses are for the configured site: same anchor, same sensors.
    /// Every difference is listed, so the log says exactly why saved poses were not used.
    pub fn matches(&self, config: &Config, path: &Path) -> Result<(), StateError> {
        let mut problems = Vec::new();
        if self.anchor != config.site.anchor {
            problems.push(format!(
                "anchor is {:?} in the file but {:?} in the config",
                self.anchor, config.site.anchor
            ));
        }
        let saved: BTreeSet<&str> = self.sensors.iter().map(|s| s.id.as_str()).collect();
        let configured: BTreeSet<&str> = config.sensors.iter().map(|s| s.id.as_str()).collect();
        let missing: Vec<&str> = configured.difference(&saved).copied().collect();
        let extra: Vec<&str> = saved.difference(&configured).copied().collect();
        if !missing.is_empty() {
            problems.push(format!("no saved pose for {}", missing.join(", ")));
        }
        if !extra.is_empty() {
            problems.push(format!("saved poses for unconfigured {}", extra.join(", ")));
        }
        if problems.is_empty() {
            Ok(())
        } else {
            Err(StateError::Mismatch {
                path: path.to_path_buf(),
                problems,
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::{Duration, UNIX_EPOCH};

    fn example() -> PosesFile {
        let t = UNIX_EPOCH + Duration::from_secs(1_790_000_000);
        let mut b = SensorPose::unregistered("b", "");
        b.registered = true;
        b.reason = None;
        b.x_m = Some(3.25);
        b.y_m = Some(-1.5);
        b.yaw_deg = Some(92.5);
        b.z_m = Some(1.0);
        b.pitch_deg = Some(0.0);
        b.sigma_x_m = Some(0.01);
        b.sigma_y_m = Some(0.02);
        b.sigma_yaw_deg = Some(0.1);
        let mut a = b.clone();
        a.id = "a".into();
        a.x_m = Some(0.0);
        a.y_m = Some(0.0);
        a.yaw_deg = Some(0.0);
        PosesFile {
            anchor: "a".into(),
            sensors: vec![
                SavedPose::from_pose(&a, PoseSource::Registered, t),
                SavedPose::from_pose(&b, PoseSource::ReRegistered, t),
                SavedPose::from_pose(
                    &SensorPose::unregistered("c", "no overlap with a or b"),
                    PoseSource::Registered,
                    t,
                ),
            ],
            building_from_site: None,
        }
    }

    #[test]
    fn poses_round_trip_through_toml_with_the_design_fields() {
        let file = example();
        let text = file.to_toml().unwrap();
        assert!(text.contains("anchor = \"a\""), "{text}");
        assert!(text.contains("[[sensor]]"), "{text}");
        assert!(text.contains("source = \"re-registered\""), "{text}");
        assert!(text.contains("updated = \"2026-09-21T"), "{text}");
        let back = PosesFile::parse(&text, Path::new("poses.toml")).unwrap();
        assert_eq!(back, file);
        let pose = back.sensors[1].to_pose(UNIX_EPOCH + Duration::from_secs(1_790_000_010));
        assert_eq!(pose.source, Some(PoseSource::Saved));
        assert_eq!(pose.age_s, Some(10.0));
        assert_eq!(pose.yaw_deg, Some(92.5));
    }

    #[test]
    fn building_from_site_is_kept_beside_the_poses_and_old_files_still_load() {
        // A file written before drawings has no `[building_from_site]`: it loads as None and
        // writes back without one.
        let old = example().to_toml().unwrap();
        assert!(!old.contains("building_from_site"), "{old}");
        let back = PosesFile::parse(&old, Path::new("poses.toml")).unwrap();
        assert_eq!(back.building_from_site, None);
        let mut file = example();
        file.building_from_site = Some(crate::drawing::BuildingFromSite {
            x_m: 12.5,
            y_m: -3.0,
            yaw_deg: 23.0,
            scale: 1.0,
            aligned: true,
            method: "automatic+lines".into(),
            reason: None,
            ..Default::default()
        });
        let text = file.to_toml().unwrap();
        assert!(text.contains("[building_from_site]"), "{text}");
        assert!(text.contains("yaw_deg = 23.0"), "{text}");
        let back = PosesFile::parse(&text, Path::new("poses.toml")).unwrap();
        assert_eq!(back, file);
        // The poses themselves stay in the anchor's frame.
        assert_eq!(back.sensors[1].x_m, Some(3.25));
    }

    #[test]
    fn an_unregistered_sensor_has_no_source_in_the_file() {
        let text = example().to_toml().unwrap();
        let c = text.split("[[sensor]]").nth(3).expect("the third sensor");
        assert!(
            c.contains("id = \"c\"") && c.contains("registered = false"),
            "{c}"
        );
        assert!(!c.contains("source"), "{c}");
        let back = PosesFile::parse(&text, Path::new("poses.toml")).unwrap();
        assert_eq!(back.sensors[2].source, None);
        assert_eq!(back.sensors[2].to_pose(UNIX_EPOCH).source, None);
        // A file from before, with `source = "registered"` beside `registered = false`, loads
        // and the stray source is dropped.
        let old = text.replace(
            "registered = false\n",
            "registered = false\nsource = \"registered\"\n",
        );
        assert_ne!(old, text);
        let back = PosesFile::parse(&old, Path::new("poses.toml")).unwrap();
        assert_eq!(back.sensors[2].source, None);
        assert!(
            !back
                .to_toml()
                .unwrap()
                .split("[[sensor]]")
                .nth(3)
                .unwrap()
                .contains("source")
        );
    }

    #[test]
    fn inconsistent_files_are_rejected_with_the_reason() {
        let text = example().to_toml().unwrap();
        let cases = [
            (
                text.replace("anchor = \"a\"", "anchor = \"z\""),
                "anchor \"z\" has no",
            ),
            (
                text.replacen("id = \"b\"", "id = \"a\"", 1),
                "appears twice",
            ),
            (text.replacen("x_m = 3.25\n", "", 1), "lacks a finite"),
            (
                text.replace("source = \"re-registered\"\n", ""),
                "registered but has no source",
            ),
            (
                text.replace("source = \"re-registered\"", "source = \"saved\""),
                "not \"saved\"",
            ),
            (
                text.replacen("updated = \"2026", "updated = \"yesterday", 1),
                "RFC 3339",
            ),
            (
                text.replacen("registered = true", "registered = true\ncolour = 1", 1),
                "unknown field `colour`",
            ),
        ];
        for (bad, want) in cases {
            assert_ne!(bad, text, "{want}");
            let err = PosesFile::parse(&bad, Path::new("p.toml"))
                .unwrap_err()
                .to_string();
            assert!(err.contains(want), "{want}: {err}");
        }
    }

    #[test]
    fn a_file_for_other_sensors_is_reported_not_used() {
        let config = crate::daemon::config::Config::parse(
            "[site]\nname = \"s\"\nanchor = \"a\"\n[[sensor]]\nid = \"a\"\nconnect = \"tcp://h:1\"\n[[sensor]]\nid = \"d\"\nconnect = \"tcp://h:2\"\n",
            Path::new("/c/site.toml"),
        )
        .unwrap();
        let err = example()
            .matches(&config, Path::new("/s/poses.toml"))
            .unwrap_err();
        let text = err.to_string();
        assert!(text.contains("no saved pose for d"), "{text}");
        assert!(text.contains("unconfigured b, c"), "{text}");
        let mut only = example();
        only.sensors.retain(|s| s.id == "a");
        only.sensors.push(SavedPose {
            id: "d".into(),
            ..only.sensors[0].clone()
        });
        assert!(only.matches(&config, Path::new("p")).is_ok());
    }
}
