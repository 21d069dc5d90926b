//! The `scanfuse.sensor` and `scanfuse.move` metadata records: string maps ⇄ typed values.
//!
//! Keys per DESIGN.md "Formats": `id`, `model`, `connect`, the PP/VV/II fields under their own
//! upper-case names, `height_m`, `pitch_deg`, and in simulated recordings `truth_x`, `truth_y`,
//! `truth_yaw_deg`. A move record holds `id`, `at_ns` and the truth keys of the pose after it.

use std::collections::BTreeMap;

use crate::scan::{MoveTruth, ScanGeometry, SensorInfo, TruthPose};

/// Name of the metadata record describing one sensor.
pub const SENSOR_RECORD: &str = "scanfuse.sensor";
/// Name of the metadata record giving a sensor's true pose after a move.
pub const MOVE_RECORD: &str = "scanfuse.move";

/// Lower-case keys with a meaning of their own; every other key is a PP/VV/II field.
const OWN_KEYS: [&str; 8] = [
    "id",
    "model",
    "connect",
    "height_m",
    "pitch_deg",
    "truth_x",
    "truth_y",
    "truth_yaw_deg",
];

/// PP keys that make up a [`ScanGeometry`].
const GEOMETRY_KEYS: [&str; 7] = ["DMIN", "DMAX", "ARES", "AMIN", "AMAX", "AFRT", "SCAN"];

pub fn sensor_to_map(sensor: &SensorInfo) -> BTreeMap<String, String> {
    let mut map = sensor.fields.clone();
    if let Some(geometry) = &sensor.geometry {
        map.extend(geometry.to_fields());
    }
    map.insert("id".into(), sensor.id.clone());
    map.insert("model".into(), sensor.model.clone());
    map.insert("connect".into(), sensor.connect.clone());
    let mut put = |key: &str, value: Option<f64>| {
        if let Some(v) = value {
            map.insert(key.into(), v.to_string());
        }
    };
    put("height_m", sensor.height_m);
    put("pitch_deg", sensor.pitch_deg);
    put("truth_x", sensor.truth.map(|t| t.x_m));
    put("truth_y", sensor.truth.map(|t| t.y_m));
    put("truth_yaw_deg", sensor.truth.map(|t| t.yaw_deg));
    map
}

/// Reads a `scanfuse.sensor` record. The error says which key is wrong and why.
pub fn sensor_from_map(map: &BTreeMap<String, String>) -> Result<SensorInfo, String> {
    let id = map
        .get("id")
        .filter(|id| !id.is_empty())
        .ok_or("the `id` key is missing or empty")?
        .clone();
    let fields: BTreeMap<String, String> = map
        .iter()
        .filter(|(k, _)| !OWN_KEYS.contains(&k.as_str()))
        .map(|(k, v)| (k.clone(), v.clone()))
        .collect();
    let geometry = if GEOMETRY_KEYS.iter().any(|k| fields.contains_key(*k)) {
        Some(ScanGeometry::from_fields(&fields).map_err(|e| format!("sensor {id}: {e}"))?)
    } else {
        None
    };
    Ok(SensorInfo {
        model: map.get("model").cloned().unwrap_or_default(),
        connect: map.get("connect").cloned().unwrap_or_default(),
        geometry,
        fields,
        height_m: number(map, "height_m").map_err(|e| format!("sensor {id}: {e}"))?,
        pitch_deg: number(map, "pitch_deg").map_err(|e| format!("sensor {id}: {e}"))?,
        truth: truth(map).map_err(|e| format!("sensor {id}: {e}"))?,
        id,
    })
}

pub fn move_to_map(moved: &MoveTruth) -> BTreeMap<String, String> {
    let mut map = BTreeMap::new();
    map.insert("id".to_string(), moved.sensor_id.clone());
    map.insert("at_ns".to_string(), moved.at_ns.to_string());
    map.insert("truth_x".to_string(), moved.pose.x_m.to_string());
    map.insert("truth_y".to_string(), moved.pose.y_m.to_string());
    map.insert("truth_yaw_deg".to_string(), moved.pose.yaw_deg.to_string());
    map
}

/// Reads a `scanfuse.move` record.
pub fn move_from_map(map: &BTreeMap<String, String>) -> Result<MoveTruth, String> {
    let sensor_id = map.get("id").ok_or("the `id` key is missing")?.clone();
    let at_ns = map
        .get("at_ns")
        .ok_or("the `at_ns` key is missing")?
        .parse()
        .map_err(|_| "`at_ns` is not a whole number of nanoseconds".to_string())?;
    let pose = truth(map)?.ok_or("the truth_x/truth_y/truth_yaw_deg keys are missing")?;
    Ok(MoveTruth {
        sensor_id,
        at_ns,
        pose,
    })
}

fn number(map: &BTreeMap<String, String>, key: &str) -> Result<Option<f64>, String> {
    let Some(text) = map.get(key) else {
        return Ok(None);
    };
    match text.trim().parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(Some(v)),
        _ => Err(format!("`{key}` = {text:?} is not a finite number")),
    }
}

fn truth(map: &BTreeMap<String, String>) -> Result<Option<TruthPose>, String> {
    let x = number(map, "truth_x")?;
    let y = number(map, "truth_y")?;
    let yaw = number(map, "truth_yaw_deg")?;
    match (x, y, yaw) {
        (Some(x_m), Some(y_m), Some(yaw_deg)) => Ok(Some(TruthPose { x_m, y_m, yaw_deg })),
        (None, None, None) => Ok(None),
        _ => Err("truth_x, truth_y and truth_yaw_deg must be given together".into()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sensor() -> SensorInfo {
        let mut s = SensorInfo::new("door", "UTM-30LX-EW");
        s.connect = "sim:lab".into();
        s.geometry = Some(ScanGeometry::UTM_30LX_EW);
        s.fields.insert("SERI".into(), "H1234567".into());
        s.fields.insert("MODL".into(), "UTM-30LX-EW".into());
        s.fields.extend(ScanGeometry::UTM_30LX_EW.to_fields());
        s.height_m = Some(1.2);
        s.pitch_deg = Some(-20.0);
        s.truth = Some(TruthPose {
            x_m: 1.5,
            y_m: -2.25,
            yaw_deg: 93.5,
        });
        s
    }

    #[test]
    fn sensor_round_trips() {
        let s = sensor();
        let map = sensor_to_map(&s);
        assert_eq!(map["truth_yaw_deg"], "93.5");
        assert_eq!(map["AFRT"], "540");
        assert_eq!(sensor_from_map(&map), Ok(s));
    }

    #[test]
    fn bad_values_are_named() {
        let mut map = sensor_to_map(&sensor());
        map.insert("truth_x".into(), "east".into());
        let err = sensor_from_map(&map).unwrap_err();
        assert!(err.contains("door") && err.contains("truth_x"), "{err}");
        let mut map = sensor_to_map(&sensor());
        map.remove("truth_y");
        assert!(sensor_from_map(&map).unwrap_err().contains("together"));
        let mut map = sensor_to_map(&sensor());
        map.insert("DMAX".into(), "1".into());
        assert!(sensor_from_map(&map).unwrap_err().contains("DMIN"));
        map.remove("id");
        assert!(sensor_from_map(&map).unwrap_err().contains("id"));
    }

    #[test]
    fn move_round_trips() {
        let m = MoveTruth {
            sensor_id: "door".into(),
            at_ns: 1_767_225_601_000_000_000,
            pose: TruthPose {
                x_m: 2.0,
                y_m: 0.5,
                yaw_deg: -10.0,
            },
        };
        assert_eq!(move_from_map(&move_to_map(&m)), Ok(m));
    }
}
