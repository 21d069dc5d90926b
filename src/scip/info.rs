//! VV, PP and II replies: `KEY:VALUE;sum` lines into typed structs. Values may themselves
//! contain `:` or `;` (the key ends at the first `:`, the value at the last `;`).

use std::collections::BTreeMap;

use thiserror::Error;

use super::checksum::checksum;
use super::encoding;
use super::reply::{Reply, push_field};
use crate::scan::{GeometryError, ScanGeometry};

#[derive(Debug, PartialEq, Eq, Error)]
#[non_exhaustive]
pub enum InfoError {
    #[error("line {line} {text:?} is not KEY:VALUE;sum")]
    Malformed { line: usize, text: String },
    #[error("line {line} {text:?} has a wrong checksum")]
    Checksum { line: usize, text: String },
    #[error("field {0} is missing")]
    Missing(&'static str),
    #[error("II TIME {0:?} is neither 6 hex digits nor 4 SCIP characters")]
    BadTime(String),
    #[error(transparent)]
    Geometry(#[from] GeometryError),
}

/// All fields of a VV/PP/II reply, in key order.
pub fn fields(reply: &Reply<'_>) -> Result<BTreeMap<String, String>, InfoError> {
    let mut out = BTreeMap::new();
    for (i, line) in reply.lines().enumerate() {
        let text = || String::from_utf8_lossy(line).into_owned();
        let malformed = || InfoError::Malformed {
            line: i + 1,
            text: text(),
        };
        let (&sum, rest) = line.split_last().ok_or_else(malformed)?;
        let body = rest.strip_suffix(b";").ok_or_else(malformed)?;
        if checksum(body) != sum {
            return Err(InfoError::Checksum {
                line: i + 1,
                text: text(),
            });
        }
        let colon = body.iter().position(|&b| b == b':').ok_or_else(malformed)?;
        let key = body.get(..colon).unwrap_or_default();
        let value = body.get(colon + 1..).unwrap_or_default();
        out.insert(
            String::from_utf8_lossy(key).into_owned(),
            String::from_utf8_lossy(value).into_owned(),
        );
    }
    Ok(out)
}

fn take(fields: &BTreeMap<String, String>, key: &'static str) -> Result<String, InfoError> {
    fields.get(key).cloned().ok_or(InfoError::Missing(key))
}

/// Writes a VV/PP/II reply with these fields, in the order given.
pub fn encode_fields<'a>(
    echo: &[u8],
    fields: impl IntoIterator<Item = (&'a str, &'a str)>,
) -> Vec<u8> {
    let mut out = Vec::with_capacity(256);
    out.extend_from_slice(echo);
    out.extend_from_slice(b"\n00P\n");
    for (key, value) in fields {
        push_field(&mut out, key, value);
    }
    out.push(b'\n');
    out
}

/// VV: who made the sensor and which firmware it runs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VersionInfo {
    pub vendor: String,
    pub product: String,
    pub firmware: String,
    pub protocol: String,
    pub serial: String,
    pub fields: BTreeMap<String, String>,
}

impl VersionInfo {
    pub fn parse(reply: &Reply<'_>) -> Result<Self, InfoError> {
        let fields = fields(reply)?;
        Ok(VersionInfo {
            vendor: take(&fields, "VEND")?,
            product: take(&fields, "PROD")?,
            firmware: take(&fields, "FIRM")?,
            protocol: take(&fields, "PROT")?,
            serial: take(&fields, "SERI")?,
            fields,
        })
    }
}

/// PP: model and scan geometry.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Parameters {
    pub model: String,
    pub geometry: ScanGeometry,
    pub fields: BTreeMap<String, String>,
}

impl Parameters {
    pub fn parse(reply: &Reply<'_>) -> Result<Self, InfoError> {
        let fields = fields(reply)?;
        Ok(Parameters {
            model: take(&fields, "MODL")?,
            geometry: ScanGeometry::from_fields(&fields)?,
            fields,
        })
    }
}

/// II: the sensor's state now.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StateInfo {
    pub model: String,
    /// `LASR:ON`.
    pub laser_on: bool,
    /// `SCSP`, e.g. `Initial(2400[rpm])`.
    pub motor_speed: String,
    /// `MESM`, e.g. `CLASSIC`, `Measuring`.
    pub measure_mode: String,
    /// `TIME`: the sensor's ms clock (24 bits), hex on old firmware, SCIP-encoded on new.
    pub time_ms: u32,
    /// `STAT`, e.g. `Sensor works well.`
    pub status: String,
    pub fields: BTreeMap<String, String>,
}

impl StateInfo {
    pub fn parse(reply: &Reply<'_>) -> Result<Self, InfoError> {
        let fields = fields(reply)?;
        let time = take(&fields, "TIME")?;
        Ok(StateInfo {
            model: take(&fields, "MODL")?,
            laser_on: take(&fields, "LASR")?.starts_with("ON"),
            motor_speed: fields.get("SCSP").cloned().unwrap_or_default(),
            measure_mode: fields.get("MESM").cloned().unwrap_or_default(),
            time_ms: parse_time(&time).ok_or(InfoError::BadTime(time))?,
            status: fields.get("STAT").cloned().unwrap_or_default(),
            fields,
        })
    }
}

/// II `TIME`: 6 hex digits (e.g. `4991D0`) or 4 SCIP characters.
pub fn parse_time(text: &str) -> Option<u32> {
    match text.len() {
        6 => u32::from_str_radix(text, 16).ok(),
        4 => encoding::decode(text.as_bytes()).ok(),
        _ => None,
    }
}

/// Time in a TM1 reply: one line of 4 characters plus checksum.
pub fn parse_tm1(reply: &Reply<'_>) -> Option<u32> {
    let mut lines = reply.lines();
    match (lines.next(), lines.next()) {
        (Some(line), None) => {
            let payload = super::checksum::verified_payload(line)?;
            if payload.len() != 4 {
                return None;
            }
            encoding::decode(payload).ok()
        }
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scip::Framer;

    #[test]
    fn values_with_colons_and_semicolons_survive() {
        let bytes = encode_fields(
            b"II",
            [
                ("STAT", "a:b;c"),
                ("MODL", "X"),
                ("LASR", "OFF"),
                ("TIME", "0Ab1"),
            ],
        );
        let mut framer = Framer::new();
        framer.push(&bytes);
        let frame = framer.next_frame().unwrap();
        let info = StateInfo::parse(&Reply::parse(&frame).unwrap()).unwrap();
        assert_eq!(info.status, "a:b;c");
        assert!(!info.laser_on);
        assert_eq!(info.time_ms, encoding::decode(b"0Ab1").unwrap());
        assert_eq!(parse_time("4991D0"), Some(0x4991D0));
        assert_eq!(parse_time("49x1D0"), None);
    }
}
