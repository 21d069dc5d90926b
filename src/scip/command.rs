//! Commands the host sends: encoding (driver side) and parsing with the spec's status codes
//! (emulator side). A command line is `SYMBOL PARAMETERS [;TAG] LF`; the sensor echoes it back
//! byte for byte, so the tag lets a host match replies to requests.

use thiserror::Error;

/// What a scan command returns per step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum DataKind {
    /// `MD`/`GD`: range, 3 characters.
    Range,
    /// `MS`/`GS`: range, 2 characters (≤ 4095 mm).
    ShortRange,
    /// `ME`/`GE`: range and intensity, 3 characters each.
    RangeIntensity,
    /// `ND`/`HD`: up to 3 echoes of range, later echoes prefixed by `&`.
    MultiRange,
    /// `NE`/`HE`: up to 3 echoes of range and intensity.
    MultiRangeIntensity,
}

impl DataKind {
    /// Characters of one range value.
    pub fn range_width(self) -> usize {
        if self == DataKind::ShortRange { 2 } else { 3 }
    }
    pub fn has_intensity(self) -> bool {
        matches!(
            self,
            DataKind::RangeIntensity | DataKind::MultiRangeIntensity
        )
    }
    pub fn is_multi_echo(self) -> bool {
        matches!(self, DataKind::MultiRange | DataKind::MultiRangeIntensity)
    }
    /// Characters per echo (range, plus intensity when sent).
    pub fn echo_width(self) -> usize {
        if self.has_intensity() {
            6
        } else {
            self.range_width()
        }
    }
    /// Command letters for continuous (`MD`…) or single (`GD`…) acquisition.
    pub fn symbol(self, continuous: bool) -> [u8; 2] {
        let (a, b) = match self {
            DataKind::Range => (b'M', b'D'),
            DataKind::ShortRange => (b'M', b'S'),
            DataKind::RangeIntensity => (b'M', b'E'),
            DataKind::MultiRange => (b'N', b'D'),
            DataKind::MultiRangeIntensity => (b'N', b'E'),
        };
        let a = match (continuous, a) {
            (true, a) => a,
            (false, b'M') => b'G',
            (false, _) => b'H',
        };
        [a, b]
    }
    /// The inverse of [`DataKind::symbol`]: kind and whether it streams.
    pub fn from_symbol(symbol: [u8; 2]) -> Option<(DataKind, bool)> {
        let kind = match &symbol {
            b"MD" | b"GD" => DataKind::Range,
            b"MS" | b"GS" => DataKind::ShortRange,
            b"ME" | b"GE" => DataKind::RangeIntensity,
            b"ND" | b"HD" => DataKind::MultiRange,
            b"NE" | b"HE" => DataKind::MultiRangeIntensity,
            _ => return None,
        };
        Some((kind, matches!(symbol[0], b'M' | b'N')))
    }
}

/// TM control code.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TimeControl {
    /// `TM0`: enter time-adjust mode (laser off).
    Enter,
    /// `TM1`: read the sensor's ms clock.
    Read,
    /// `TM2`: leave time-adjust mode.
    Leave,
}

/// Parameters of a scan command (`MD`…`HE`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScanRequest {
    pub kind: DataKind,
    /// `M*`/`N*` stream; `G*`/`H*` return one scan.
    pub continuous: bool,
    pub start_step: u16,
    pub end_step: u16,
    /// Adjacent steps merged into one value (0 and 1 both mean none).
    pub cluster: u8,
    /// Scans skipped between sent scans (continuous only).
    pub interval: u8,
    /// Scans to send, 0 = until QT (continuous only).
    pub scans: u8,
}

impl ScanRequest {
    /// Values per scan: `ceil((end - start + 1) / cluster)`.
    pub fn value_count(&self) -> usize {
        let steps = (self.end_step as usize + 1).saturating_sub(self.start_step as usize);
        steps.div_ceil(self.cluster.max(1) as usize)
    }
}

/// Every command of SCIP 2.0 that scanfuse speaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// `VV`: vendor, product, firmware, protocol, serial.
    Version,
    /// `PP`: model and scan geometry.
    Parameters,
    /// `II`: state (laser, motor, mode, clock).
    Info,
    /// `BM`: laser on.
    LaserOn,
    /// `QT`: stop streaming, laser off, leave time-adjust mode.
    Quit,
    /// `RS`: reset all settings.
    Reset,
    /// `RT`: reset all but motor speed and bit rate.
    ResetPartial,
    /// `RB`: reboot (must be sent twice within a second).
    Reboot,
    /// `TM0`/`TM1`/`TM2`.
    Time(TimeControl),
    /// `SS`: serial bit rate, bps (6 digits).
    BitRate(u32),
    /// `CR`: motor speed code, 00 = default, 01–10 = slower, 99 = reset.
    MotorSpeed(u8),
    /// `HS`: high-sensitivity mode.
    HighSensitivity(bool),
    /// `%ST`: self-test/state line (UST-series; hokuyolx sends it).
    SensorState,
    /// `MD`…`HE`.
    Scan(ScanRequest),
}

/// A command plus the optional `;tag` the sensor echoes back.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Request {
    pub command: Command,
    pub tag: Option<String>,
}

/// Why a command line is not a valid command; `status()` is what a sensor answers.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
#[non_exhaustive]
pub enum RequestError {
    #[error("unknown command {0:?}")]
    Undefined(String),
    #[error("too few or too many parameter characters")]
    WrongLength,
    #[error("parameter {index} is not a number")]
    NotANumber { index: u8 },
    #[error("end step is before start step")]
    EndBeforeStart,
    #[error("invalid TM control code")]
    BadTimeControl,
    #[error("tag is longer than 16 characters")]
    TagTooLong,
    #[error("tag has a character outside letters, digits, space and . _ + @")]
    TagInvalid,
}

impl RequestError {
    /// The status a SCIP 2.0 sensor sends for this error to command `symbol`.
    pub fn status(&self) -> [u8; 2] {
        match self {
            RequestError::Undefined(_) => *b"0E",
            RequestError::WrongLength => *b"0C",
            RequestError::NotANumber { index } => [b'0', b'0' + index],
            RequestError::EndBeforeStart => *b"05",
            RequestError::BadTimeControl => *b"01",
            RequestError::TagTooLong => *b"0G",
            RequestError::TagInvalid => *b"0H",
        }
    }
}

fn tag_char_ok(c: u8) -> bool {
    c.is_ascii_alphanumeric() || matches!(c, b' ' | b'.' | b'_' | b'+' | b'@')
}

impl Request {
    pub fn new(command: Command) -> Self {
        Request { command, tag: None }
    }

    pub fn tagged(command: Command, tag: impl Into<String>) -> Self {
        Request {
            command,
            tag: Some(tag.into()),
        }
    }

    /// The command line without its LF, which is also the echo a sensor sends back.
    pub fn line(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(24);
        match self.command {
            Command::Version => out.extend_from_slice(b"VV"),
            Command::Parameters => out.extend_from_slice(b"PP"),
            Command::Info => out.extend_from_slice(b"II"),
            Command::LaserOn => out.extend_from_slice(b"BM"),
            Command::Quit => out.extend_from_slice(b"QT"),
            Command::Reset => out.extend_from_slice(b"RS"),
            Command::ResetPartial => out.extend_from_slice(b"RT"),
            Command::Reboot => out.extend_from_slice(b"RB"),
            Command::SensorState => out.extend_from_slice(b"%ST"),
            Command::Time(c) => out.extend_from_slice(match c {
                TimeControl::Enter => b"TM0",
                TimeControl::Read => b"TM1",
                TimeControl::Leave => b"TM2",
            }),
            Command::BitRate(bps) => {
                out.extend_from_slice(format!("SS{:06}", bps % 1_000_000).as_bytes())
            }
            Command::MotorSpeed(code) => {
                out.extend_from_slice(format!("CR{:02}", code % 100).as_bytes())
            }
            Command::HighSensitivity(on) => out.extend_from_slice(if on { b"HS1" } else { b"HS0" }),
            Command::Scan(s) => {
                out.extend_from_slice(&s.kind.symbol(s.continuous));
                let mut params = format!(
                    "{:04}{:04}{:02}",
                    s.start_step % 10_000,
                    s.end_step % 10_000,
                    s.cluster % 100
                );
                if s.continuous {
                    params.push_str(&format!("{:01}{:02}", s.interval % 10, s.scans % 100));
                }
                out.extend_from_slice(params.as_bytes());
            }
        }
        if let Some(tag) = &self.tag {
            out.push(b';');
            out.extend_from_slice(tag.as_bytes());
        }
        out
    }

    /// The bytes to send: the line and LF.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = self.line();
        out.push(b'\n');
        out
    }

    /// Parses one command line (without LF/CR), as a sensor does.
    pub fn parse(line: &[u8]) -> Result<Request, RequestError> {
        let (body, tag) = match line.iter().position(|&c| c == b';') {
            Some(i) => {
                let tag = line.get(i + 1..).unwrap_or_default();
                if tag.len() > 16 {
                    return Err(RequestError::TagTooLong);
                }
                if !tag.iter().all(|&c| tag_char_ok(c)) {
                    return Err(RequestError::TagInvalid);
                }
                (
                    line.get(..i).unwrap_or_default(),
                    Some(String::from_utf8_lossy(tag).into_owned()),
                )
            }
            None => (line, None),
        };
        let undefined = || RequestError::Undefined(String::from_utf8_lossy(body).into_owned());
        let (symbol, params) = match body {
            [b'%', b'S', b'T'] => {
                return Ok(Request {
                    command: Command::SensorState,
                    tag,
                });
            }
            [a, b, rest @ ..] => ([*a, *b], rest),
            _ => return Err(undefined()),
        };
        let no_params = |command: Command| {
            if params.is_empty() {
                Ok(command)
            } else {
                Err(RequestError::WrongLength)
            }
        };
        let command = match &symbol {
            b"VV" => no_params(Command::Version)?,
            b"PP" => no_params(Command::Parameters)?,
            b"II" => no_params(Command::Info)?,
            b"BM" => no_params(Command::LaserOn)?,
            b"QT" => no_params(Command::Quit)?,
            b"RS" => no_params(Command::Reset)?,
            b"RT" => no_params(Command::ResetPartial)?,
            b"RB" => no_params(Command::Reboot)?,
            b"TM" => match params {
                b"0" => Command::Time(TimeControl::Enter),
                b"1" => Command::Time(TimeControl::Read),
                b"2" => Command::Time(TimeControl::Leave),
                [_] => return Err(RequestError::BadTimeControl),
                _ => return Err(RequestError::WrongLength),
            },
            b"SS" => Command::BitRate(number(params, 6, 1)?),
            b"CR" => Command::MotorSpeed(number(params, 2, 1)? as u8),
            b"HS" => match params {
                b"0" => Command::HighSensitivity(false),
                b"1" => Command::HighSensitivity(true),
                [_] => return Err(RequestError::NotANumber { index: 1 }),
                _ => return Err(RequestError::WrongLength),
            },
            _ => {
                let (kind, continuous) = DataKind::from_symbol(symbol).ok_or_else(undefined)?;
                let expected = if continuous { 13 } else { 10 };
                if params.len() != expected {
                    return Err(RequestError::WrongLength);
                }
                let field = |from: usize, len: usize, index: u8| {
                    number(params.get(from..from + len).unwrap_or_default(), len, index)
                };
                let start_step = field(0, 4, 1)? as u16;
                let end_step = field(4, 4, 2)? as u16;
                let cluster = field(8, 2, 3)? as u8;
                let (interval, scans) = if continuous {
                    (field(10, 1, 6)? as u8, field(11, 2, 7)? as u8)
                } else {
                    (0, 0)
                };
                if end_step < start_step {
                    return Err(RequestError::EndBeforeStart);
                }
                Command::Scan(ScanRequest {
                    kind,
                    continuous,
                    start_step,
                    end_step,
                    cluster,
                    interval,
                    scans,
                })
            }
        };
        Ok(Request { command, tag })
    }
}

/// A decimal field of exactly `len` digits.
fn number(digits: &[u8], len: usize, index: u8) -> Result<u32, RequestError> {
    if digits.len() != len {
        return Err(RequestError::WrongLength);
    }
    if !digits.iter().all(u8::is_ascii_digit) {
        return Err(RequestError::NotANumber { index });
    }
    Ok(digits
        .iter()
        .fold(0u32, |acc, &d| acc * 10 + (d - b'0') as u32))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn scan_commands_encode_as_the_captures_sent_them() {
        let me = ScanRequest {
            kind: DataKind::RangeIntensity,
            continuous: true,
            start_step: 0,
            end_step: 1080,
            cluster: 1,
            interval: 0,
            scans: 1,
        };
        assert_eq!(
            Request::new(Command::Scan(me)).encode(),
            b"ME0000108001001\n"
        );
        let gd = ScanRequest {
            kind: DataKind::Range,
            continuous: false,
            start_step: 44,
            end_step: 725,
            ..me
        };
        assert_eq!(Request::new(Command::Scan(gd)).encode(), b"GD0044072501\n");
        assert_eq!(
            Request::tagged(Command::Time(TimeControl::Read), "a1").encode(),
            b"TM1;a1\n"
        );
        assert_eq!(Request::new(Command::SensorState).encode(), b"%ST\n");
        assert_eq!(gd.value_count(), 682);
    }

    #[test]
    fn bad_parameters_map_to_the_specs_status_codes() {
        let status = |line: &[u8]| Request::parse(line).unwrap_err().status();
        assert_eq!(status(b"MDx000108001000"), *b"01");
        assert_eq!(status(b"MD00001x8001000"), *b"02");
        assert_eq!(status(b"MD000010800x000"), *b"03");
        assert_eq!(status(b"MD0000108001x00"), *b"06");
        assert_eq!(status(b"MD000010800100x"), *b"07");
        assert_eq!(status(b"MD0100000501000"), *b"05");
        assert_eq!(status(b"MD00001080"), *b"0C");
        assert_eq!(status(b"XX"), *b"0E");
        assert_eq!(status(b"TM7"), *b"01");
        assert_eq!(status(b"VV;12345678901234567"), *b"0G");
        assert_eq!(status(b"VV;a#"), *b"0H");
    }

    fn any_request() -> impl Strategy<Value = Request> {
        let kind = prop_oneof![
            Just(DataKind::Range),
            Just(DataKind::ShortRange),
            Just(DataKind::RangeIntensity),
            Just(DataKind::MultiRange),
            Just(DataKind::MultiRangeIntensity)
        ];
        let scan = (
            kind,
            any::<bool>(),
            0u16..5000,
            0u16..5000,
            0u8..100,
            0u8..10,
            0u8..100,
        )
            .prop_map(|(kind, continuous, a, b, cluster, interval, scans)| {
                Command::Scan(ScanRequest {
                    kind,
                    continuous,
                    start_step: a.min(b),
                    end_step: a.max(b),
                    cluster,
                    interval: if continuous { interval } else { 0 },
                    scans: if continuous { scans } else { 0 },
                })
            });
        let command = prop_oneof![
            Just(Command::Version),
            Just(Command::Parameters),
            Just(Command::Info),
            Just(Command::LaserOn),
            Just(Command::Quit),
            Just(Command::Reset),
            Just(Command::ResetPartial),
            Just(Command::Reboot),
            Just(Command::SensorState),
            Just(Command::Time(TimeControl::Enter)),
            Just(Command::Time(TimeControl::Read)),
            Just(Command::Time(TimeControl::Leave)),
            (0u32..1_000_000).prop_map(Command::BitRate),
            (0u8..100).prop_map(Command::MotorSpeed),
            any::<bool>().prop_map(Command::HighSensitivity),
            scan,
        ];
        (command, proptest::option::of("[A-Za-z0-9 ._+@]{0,16}"))
            .prop_map(|(command, tag)| Request { command, tag })
    }

    proptest! {
        #[test]
        fn encode_then_parse_is_identity(request in any_request()) {
            prop_assert_eq!(Request::parse(&request.line()), Ok(request));
        }
    }
}
