//! The values every stage passes around: what a sensor is, and one scan from it.
//!
//! Drivers produce these, recordings store them, the simulator makes them and registration
//! consumes them. Nothing here does I/O.

use std::collections::BTreeMap;
use std::f64::consts::TAU;

use thiserror::Error;

/// Angular and range layout of a SCIP sensor, exactly as its PP reply states it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ScanGeometry {
    /// Shortest valid range (PP `DMIN`), mm.
    pub dmin_mm: u32,
    /// Longest valid range (PP `DMAX`), mm.
    pub dmax_mm: u32,
    /// Steps in a full turn (PP `ARES`).
    pub ares: u32,
    /// First measurable step (PP `AMIN`).
    pub amin: u32,
    /// Last measurable step (PP `AMAX`).
    pub amax: u32,
    /// Step that points straight ahead, along +x (PP `AFRT`).
    pub afrt: u32,
    /// Mirror speed (PP `SCAN`), rpm: one scan per turn.
    pub scan_rpm: u32,
}

/// A PP field was missing or not a number.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum GeometryError {
    #[error("PP field {0} is missing")]
    Missing(&'static str),
    #[error("PP field {key} = {value:?} is not a whole number")]
    NotANumber { key: &'static str, value: String },
    #[error("PP fields are inconsistent: {0}")]
    Inconsistent(String),
}

impl ScanGeometry {
    /// UTM-30LX-EW: 270° in 1,081 steps of 0.25°, 25 ms per scan, 23 mm – 60 m.
    pub const UTM_30LX_EW: ScanGeometry = ScanGeometry {
        dmin_mm: 23,
        dmax_mm: 60_000,
        ares: 1440,
        amin: 0,
        amax: 1080,
        afrt: 540,
        scan_rpm: 2400,
    };

    /// UXM-30LX-E: 190° in 761 steps of 0.25°, 50 ms per scan, 100 mm – 100 m.
    pub const UXM_30LX_E: ScanGeometry = ScanGeometry {
        dmin_mm: 100,
        dmax_mm: 100_000,
        ares: 1440,
        amin: 0,
        amax: 760,
        afrt: 380,
        scan_rpm: 1200,
    };

    /// URG-04LX: 240° (-119.5° to +119.9°) in 682 steps of 0.3515625° (1,024 to the turn),
    /// 100 ms per scan, 20 mm – 5.6 m (4 m guaranteed). The data sheet's "683 steps" counts
    /// one more than AMIN..=AMAX holds; a real unit's GD0044072501 returns 682 ranges.
    pub const URG_04LX: ScanGeometry = ScanGeometry {
        dmin_mm: 20,
        dmax_mm: 5600,
        ares: 1024,
        amin: 44,
        amax: 725,
        afrt: 384,
        scan_rpm: 600,
    };

    /// Reads the geometry from PP fields (`DMIN`, `DMAX`, `ARES`, `AMIN`, `AMAX`, `AFRT`, `SCAN`).
    pub fn from_fields(fields: &BTreeMap<String, String>) -> Result<Self, GeometryError> {
        fn get(fields: &BTreeMap<String, String>, key: &'static str) -> Result<u32, GeometryError> {
            let value = fields.get(key).ok_or(GeometryError::Missing(key))?;
            value.trim().parse().map_err(|_| GeometryError::NotANumber {
                key,
                value: value.clone(),
            })
        }
        let geometry = ScanGeometry {
            dmin_mm: get(fields, "DMIN")?,
            dmax_mm: get(fields, "DMAX")?,
            ares: get(fields, "ARES")?,
            amin: get(fields, "AMIN")?,
            amax: get(fields, "AMAX")?,
            afrt: get(fields, "AFRT")?,
            scan_rpm: get(fields, "SCAN")?,
        };
        geometry.validate()?;
        Ok(geometry)
    }

    /// Writes the geometry as PP fields, the inverse of [`ScanGeometry::from_fields`].
    pub fn to_fields(&self) -> BTreeMap<String, String> {
        [
            ("DMIN", self.dmin_mm),
            ("DMAX", self.dmax_mm),
            ("ARES", self.ares),
            ("AMIN", self.amin),
            ("AMAX", self.amax),
            ("AFRT", self.afrt),
            ("SCAN", self.scan_rpm),
        ]
        .into_iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect()
    }

    /// Checks the relations a real sensor's PP reply always satisfies.
    pub fn validate(&self) -> Result<(), GeometryError> {
        let fail = |why: String| Err(GeometryError::Inconsistent(why));
        if self.ares == 0 {
            return fail("ARES is 0".into());
        }
        if self.amin > self.amax {
            return fail(format!("AMIN {} > AMAX {}", self.amin, self.amax));
        }
        if self.amax - self.amin >= self.ares {
            return fail(format!(
                "AMIN..AMAX spans {} steps, more than a turn of {}",
                self.amax - self.amin + 1,
                self.ares
            ));
        }
        if self.dmin_mm >= self.dmax_mm {
            return fail(format!("DMIN {} >= DMAX {}", self.dmin_mm, self.dmax_mm));
        }
        if self.scan_rpm == 0 {
            return fail("SCAN is 0 rpm".into());
        }
        Ok(())
    }

    /// Number of measurable steps, AMIN..=AMAX.
    pub fn step_count(&self) -> usize {
        (self.amax - self.amin) as usize + 1
    }

    /// Angle of one step, rad: one step is a full turn / ARES.
    pub fn step_rad(&self) -> f64 {
        TAU / self.ares as f64
    }

    /// Direction of step `step` in the sensor frame (counter-clockwise from +x), rad.
    pub fn angle_of_step_rad(&self, step: u32) -> f64 {
        (step as f64 - self.afrt as f64) * self.step_rad()
    }

    /// Time for one scan, s.
    pub fn period_s(&self) -> f64 {
        60.0 / self.scan_rpm as f64
    }

    /// The step nearest to `angle_rad`, which may lie outside AMIN..=AMAX.
    pub fn step_of_angle(&self, angle_rad: f64) -> i64 {
        (angle_rad / self.step_rad()).round() as i64 + self.afrt as i64
    }
}

/// A sensor as it is known: identity, model, layout, mount and (in simulations) true pose.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorInfo {
    /// Site-unique id, also the recording topic prefix (`/<id>/scan`).
    pub id: String,
    /// Model name, e.g. `UTM-30LX-EW`.
    pub model: String,
    /// Where the scans came from: `tcp://…`, `serial://…`, `sim`, `replay:…`.
    pub connect: String,
    /// Layout from PP; `None` for recordings from other writers that do not state it.
    pub geometry: Option<ScanGeometry>,
    /// Every PP/VV/II field as the sensor reported it (`MODL`, `SERI`, `FIRM`, …), including
    /// the PP keys `geometry` was read from.
    pub fields: BTreeMap<String, String>,
    /// Height of the optical centre above the floor, m.
    pub height_m: Option<f64>,
    /// Pitch of the scan plane about the sensor's y axis, degrees, positive up.
    pub pitch_deg: Option<f64>,
    /// True pose in the site frame at the start of the recording (simulated data only).
    pub truth: Option<TruthPose>,
}

impl SensorInfo {
    /// A sensor with only an id and a model; other fields empty.
    pub fn new(id: impl Into<String>, model: impl Into<String>) -> Self {
        SensorInfo {
            id: id.into(),
            model: model.into(),
            connect: String::new(),
            geometry: None,
            fields: BTreeMap::new(),
            height_m: None,
            pitch_deg: None,
            truth: None,
        }
    }

    /// How it is mounted, as projection and registration take it (level when not stated).
    pub fn mount(&self) -> crate::geometry::Mount {
        crate::geometry::Mount {
            height_m: self.height_m,
            pitch_rad: self.pitch_deg.unwrap_or(0.0).to_radians(),
        }
    }
}

/// A pose in the site frame, as ground truth states it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthPose {
    pub x_m: f64,
    pub y_m: f64,
    pub yaw_deg: f64,
}

/// Ground truth for a sensor that was moved during a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct MoveTruth {
    pub sensor_id: String,
    /// Recording time of the move, ns (same clock as [`Scan::stamp_ns`]).
    pub at_ns: u64,
    /// The pose after the move, site frame.
    pub pose: TruthPose,
}

/// Where every simulated person is at one moment: a message of a simulated recording's
/// `/truth/people` channel (site frame). Only evaluation and tests read it.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PeopleTruth {
    /// Recording time, ns (same clock as [`Scan::stamp_ns`]).
    pub t_ns: u64,
    pub people: Vec<PersonTruth>,
}

/// One person's body centre in [`PeopleTruth`].
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct PersonTruth {
    /// `p<n>` for crowd and queue people (in order of appearance, never reused), `w<n>` for a
    /// plan's `[[person]]` walkers.
    pub id: String,
    pub x_m: f64,
    pub y_m: f64,
}

/// One scan: ranges (and maybe intensities) over an arc, stamped.
#[derive(Debug, Clone, PartialEq)]
pub struct Scan {
    /// Host receive time, ns since the Unix epoch; the recording's log time.
    pub stamp_ns: u64,
    /// The sensor's own clock at the scan, ms (unwrapped), when the source knows it.
    pub sensor_stamp_ms: Option<u64>,
    /// Direction of the first range in the sensor frame, rad.
    pub start_angle_rad: f64,
    /// Direction of the last range, rad. Ranges are evenly spaced between the two.
    pub end_angle_rad: f64,
    /// Ranges in m; 0 or NaN means no return.
    pub ranges_m: Vec<f32>,
    /// Intensities, one per range, or empty when the sensor did not send them.
    pub intensities: Vec<f32>,
}

impl Scan {
    /// The angle of range `i`, spreading ranges evenly from start to end angle.
    pub fn angle_of_index_rad(&self, i: usize) -> f64 {
        let n = self.ranges_m.len();
        if n < 2 {
            return self.start_angle_rad;
        }
        self.start_angle_rad
            + (self.end_angle_rad - self.start_angle_rad) * i as f64 / (n - 1) as f64
    }

    /// True when range `i` is a real return (not 0, not NaN, finite).
    pub fn is_return(&self, i: usize) -> bool {
        self.ranges_m
            .get(i)
            .is_some_and(|r| r.is_finite() && *r > 0.0)
    }
}

/// Checks a sensor id: it names MCAP topics (`/<id>/scan`) and config entries, so it must be
/// 1–64 characters of ASCII letters, digits, `_`, `-` or `.`.
pub fn check_sensor_id(id: &str) -> Result<(), String> {
    let ok_char = |c: char| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.');
    if id.is_empty() || id.len() > 64 || !id.chars().all(ok_char) {
        return Err(format!(
            "sensor id {id:?} is not valid: use 1–64 ASCII letters, digits, '_', '-' or '.'"
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utm_front_step_points_forward_and_ends_at_135_degrees() {
        let g = ScanGeometry::UTM_30LX_EW;
        assert_eq!(g.step_count(), 1081);
        assert_eq!(g.angle_of_step_rad(540), 0.0);
        assert!((g.angle_of_step_rad(1080).to_degrees() - 135.0).abs() < 1e-9);
        assert!((g.angle_of_step_rad(0).to_degrees() + 135.0).abs() < 1e-9);
        assert!((g.period_s() - 0.025).abs() < 1e-12);
        assert_eq!(g.step_of_angle(g.angle_of_step_rad(17)), 17);
    }

    #[test]
    fn urg_spans_240_degrees_in_682_steps_at_10_hz() {
        let g = ScanGeometry::URG_04LX;
        assert_eq!(g.validate(), Ok(()));
        assert_eq!(g.step_count(), 682);
        assert_eq!(g.angle_of_step_rad(384), 0.0);
        assert!((g.step_rad().to_degrees() - 0.3515625).abs() < 1e-12);
        // AMIN and AMAX sit 340 and 341 steps either side of the front: ±119.5°, ±119.9°.
        assert!((g.angle_of_step_rad(44).to_degrees() + 119.53125).abs() < 1e-9);
        assert!((g.angle_of_step_rad(725).to_degrees() - 119.8828125).abs() < 1e-9);
        assert!((g.period_s() - 0.1).abs() < 1e-12);
    }

    #[test]
    fn geometry_round_trips_through_pp_fields_and_rejects_nonsense() {
        let g = ScanGeometry::UXM_30LX_E;
        assert_eq!(ScanGeometry::from_fields(&g.to_fields()), Ok(g));
        let mut fields = g.to_fields();
        fields.insert("AMAX".into(), "2000".into());
        assert!(matches!(
            ScanGeometry::from_fields(&fields),
            Err(GeometryError::Inconsistent(_))
        ));
        fields.remove("ARES");
        assert_eq!(
            ScanGeometry::from_fields(&fields),
            Err(GeometryError::Missing("ARES"))
        );
    }

    #[test]
    fn sensor_ids_must_fit_in_a_topic() {
        assert!(check_sensor_id("hall-3.east_2").is_ok());
        for bad in ["", "a/b", "a b", "é", &"x".repeat(65)] {
            assert!(check_sensor_id(bad).is_err(), "{bad:?}");
        }
    }
}
