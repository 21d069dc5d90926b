//! Surveys set by hand (the page's drag, or `{"cmd":"survey"}` on the socket), kept in
//! `state_dir/surveys.toml` so that a sensor placed by hand stays placed across restarts.
//! The file is the daemon's own; it is written atomically and read back at start.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::config::Survey;
use super::state::{StateError, write_atomic};

/// The state file name, in the state directory.
pub const SURVEYS_FILE: &str = "surveys.toml";

#[derive(Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    #[serde(default)]
    sensor: Vec<Entry>,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Entry {
    id: String,
    x_m: f64,
    y_m: f64,
    yaw_deg: f64,
    sigma_xy_m: f64,
    sigma_yaw_deg: f64,
}

const HEADER: &str = "# Sensors placed by hand (the page, or {\"cmd\":\"survey\"} on the status socket).\n# scanfuse writes this file; clear a survey with {\"cmd\":\"unsurvey\",\"sensor\":\"ID\"}.\n\n";

/// Checks a survey a person sent: finite, within the config's bounds.
pub fn check(
    x_m: f64,
    y_m: f64,
    yaw_deg: f64,
    sigma_xy_m: f64,
    sigma_yaw_deg: f64,
) -> Result<Survey, String> {
    for (key, v) in [("x_m", x_m), ("y_m", y_m), ("yaw_deg", yaw_deg)] {
        if !v.is_finite() || v.abs() > 1e5 {
            return Err(format!(
                "{key} must be a finite number within ±100000, not {v}"
            ));
        }
    }
    if !(sigma_xy_m > 0.0 && sigma_xy_m <= 10.0) {
        return Err(format!(
            "sigma_xy_m must be greater than 0 and at most 10 (metres), not {sigma_xy_m}"
        ));
    }
    if !(sigma_yaw_deg > 0.0 && sigma_yaw_deg <= 180.0) {
        return Err(format!(
            "sigma_yaw_deg must be greater than 0 and at most 180 (degrees), not {sigma_yaw_deg}"
        ));
    }
    Ok(Survey {
        x_m,
        y_m,
        yaw_rad: yaw_deg.to_radians(),
        sigma_xy_m,
        sigma_yaw_rad: sigma_yaw_deg.to_radians(),
    })
}

/// The file's path in `dir`.
pub fn path_in(dir: &Path) -> PathBuf {
    dir.join(SURVEYS_FILE)
}

/// Writes every hand-set survey to `dir` (removes the file when there are none).
pub fn save(dir: &Path, surveys: &BTreeMap<String, Survey>) -> Result<(), StateError> {
    let path = path_in(dir);
    if surveys.is_empty() {
        return match std::fs::remove_file(&path) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                Err(StateError::Write { path, source: e })
            }
            _ => Ok(()),
        };
    }
    std::fs::create_dir_all(dir).map_err(|source| StateError::Write {
        path: path.clone(),
        source,
    })?;
    let file = File {
        sensor: surveys
            .iter()
            .map(|(id, s)| Entry {
                id: id.clone(),
                x_m: s.x_m,
                y_m: s.y_m,
                yaw_deg: s.yaw_rad.to_degrees(),
                sigma_xy_m: s.sigma_xy_m,
                sigma_yaw_deg: s.sigma_yaw_rad.to_degrees(),
            })
            .collect(),
    };
    let text = toml::to_string(&file).map_err(|e| StateError::Encode(e.to_string()))?;
    write_atomic(&path, format!("{HEADER}{text}").as_bytes())
}

/// Reads the hand-set surveys in `dir`; none when the file is absent.
pub fn load(dir: &Path) -> Result<BTreeMap<String, Survey>, StateError> {
    let path = path_in(dir);
    let text = match std::fs::read_to_string(&path) {
        Ok(t) => t,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(BTreeMap::new()),
        Err(source) => return Err(StateError::Read { path, source }),
    };
    let file: File = toml::from_str(&text).map_err(|e| StateError::Invalid {
        path: path.clone(),
        message: e.message().to_string(),
    })?;
    let mut out = BTreeMap::new();
    for e in file.sensor {
        let survey =
            check(e.x_m, e.y_m, e.yaw_deg, e.sigma_xy_m, e.sigma_yaw_deg).map_err(|message| {
                StateError::Invalid {
                    path: path.clone(),
                    message: format!("sensor {:?}: {message}", e.id),
                }
            })?;
        out.insert(e.id, survey);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn surveys_round_trip_and_the_file_goes_when_empty() {
        let dir = tempfile::tempdir().unwrap();
        assert!(load(dir.path()).unwrap().is_empty(), "no file, no surveys");
        let mut surveys = BTreeMap::new();
        surveys.insert(
            "dock".to_string(),
            check(1.5, -2.0, 90.0, 0.05, 2.0).unwrap(),
        );
        save(dir.path(), &surveys).unwrap();
        let back = load(dir.path()).unwrap();
        let dock = back["dock"];
        assert!((dock.x_m - 1.5).abs() < 1e-12 && (dock.yaw_rad.to_degrees() - 90.0).abs() < 1e-9);
        save(dir.path(), &BTreeMap::new()).unwrap();
        assert!(!path_in(dir.path()).exists());
    }

    #[test]
    fn bad_numbers_are_refused_with_the_key() {
        assert!(
            check(f64::NAN, 0.0, 0.0, 0.05, 2.0)
                .unwrap_err()
                .contains("x_m")
        );
        assert!(
            check(0.0, 0.0, 0.0, 0.0, 2.0)
                .unwrap_err()
                .contains("sigma_xy_m")
        );
        assert!(
            check(0.0, 0.0, 0.0, 0.1, 500.0)
                .unwrap_err()
                .contains("sigma_yaw_deg")
        );
    }
}
