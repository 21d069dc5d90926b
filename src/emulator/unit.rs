//! The emulated sensor's state machine. Pure: [`Unit::handle`] takes one command line and the
//! sensor clock and returns the reply bytes; [`Unit::stream_block`] makes the next scan block of
//! a running MD/ME/ND stream. Replies follow C-42-03320B and the UTM-30LX-EW's habits: the echo
//! is the received line byte for byte, QT also ends time-adjust mode, II reports `Measuring`
//! while streaming.

use std::collections::BTreeMap;

use crate::scan::{Scan, ScanGeometry, SensorInfo};
use crate::scip::command::{Command, Request, ScanRequest, TimeControl};
use crate::scip::encoding;
use crate::scip::info::encode_fields;
use crate::scip::reply::{encode_status, push_line};
use crate::scip::scan::{Echo, ScipScan};

/// A recorded scan as the sensor measured it: integer mm and raw intensities by step.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SourceScan {
    /// Step of `ranges_mm[0]`.
    pub first_step: i64,
    pub ranges_mm: Vec<u32>,
    pub intensities: Vec<u32>,
}

impl SourceScan {
    /// Back from metres to the mm the sensor sent; no return (0, NaN) becomes 0, an error code.
    pub fn from_scan(scan: &Scan, geometry: &ScanGeometry) -> Self {
        let to_mm = |r: f32| {
            if r.is_finite() && r > 0.0 {
                (r as f64 * 1000.0).round() as u32
            } else {
                0
            }
        };
        SourceScan {
            first_step: geometry.step_of_angle(scan.start_angle_rad),
            ranges_mm: scan.ranges_m.iter().map(|&r| to_mm(r)).collect(),
            intensities: scan
                .intensities
                .iter()
                .map(|&i| {
                    if i.is_finite() && i > 0.0 {
                        i.round().min(encoding::max_value(3) as f32) as u32
                    } else {
                        0
                    }
                })
                .collect(),
        }
    }

    fn at(&self, step: i64) -> (u32, u32) {
        let Ok(i) = usize::try_from(step - self.first_step) else {
            return (0, 0);
        };
        (
            self.ranges_mm.get(i).copied().unwrap_or(0),
            self.intensities.get(i).copied().unwrap_or(0),
        )
    }
}

#[derive(Debug, Clone, PartialEq, Eq)]
struct Stream {
    request: ScanRequest,
    /// The command line as received; the remaining-scans digits are rewritten per block.
    line: Vec<u8>,
    /// Blocks still to send; `None` streams until QT.
    remaining: Option<u8>,
    /// Scans to skip before the next block (MD's scan interval).
    skip: u8,
}

#[derive(Debug, Clone, PartialEq, Eq)]
enum Mode {
    Idle,
    TimeAdjust,
    Streaming(Stream),
}

/// What the sensor is doing, in the codes of `%ST` (UST-series; hokuyolx asks for it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum State {
    Standby,
    TimeAdjust,
    SingleScan,
    MultiScan,
}

/// One emulated sensor.
#[derive(Debug, Clone)]
pub struct Unit {
    geometry: ScanGeometry,
    version: Vec<(String, String)>,
    model: String,
    fields: BTreeMap<String, String>,
    mode: Mode,
    laser_on: bool,
    high_sensitivity: bool,
    motor_code: u8,
    /// Whether CR can change the motor speed on this model (see [`Unit::new`]).
    motor_speed_adjustable: bool,
    /// Sensor clock = `clock.start_ms + (now_ms - clock_zero_ms)·(1 + drift)`; RS/RT/RB
    /// restart it (the spec's RS "resets the sensor's internal timer").
    clock_zero_ms: u64,
    clock: ClockSetting,
    synthetic_echoes: Option<SyntheticEchoes>,
    /// Until this host time the unit is booting: TM0 and scans are refused (status `10`).
    booting_until_ms: u64,
    reboot_armed_at_ms: Option<u64>,
    streams_started: u64,
    /// Reboots done (a second RB within a second of the first).
    reboots: u64,
    /// Whether the unit knows the multi-echo commands ND NE HD HE (SCIP 2.2 units such as the
    /// UXM-30LX-E and UTM-30LX-EW do; the UTM-30LX does not).
    multi_echo: bool,
}

/// The emulated sensor clock. A real unit starts at 0 when powered on or reset and keeps
/// time with its own crystal; tests start it near the 24-bit wrap (2^24 ms ≈ 4 h 40 min)
/// instead of waiting for it, and make it drift to exercise the driver's clock model.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ClockSetting {
    /// Clock reading at power-on and after RS/RT/RB, ms (taken modulo 2^24).
    pub start_ms: u64,
    /// How much faster than the host's the sensor clock runs, parts per million.
    pub drift_ppm: f64,
}

/// Second echoes for multi-echo commands (ND NE HD HE), made up: a recording holds one echo
/// per step, so without this an emulated multi-echo scan never has a second one. Every `every`th
/// value with a range gets one echo `behind_mm` farther, with half the first echo's intensity,
/// like light passing the edge of an object. Off unless asked for; for testing clients only.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SyntheticEchoes {
    pub every: u32,
    pub behind_mm: u32,
}

impl SyntheticEchoes {
    /// The made-up echo behind value `index` whose first echo is `(range_mm, intensity)`.
    pub fn echo(&self, index: u32, range_mm: u32, intensity: u32, max_mm: u32) -> Option<Echo> {
        (self.every > 0 && index.is_multiple_of(self.every) && range_mm > 0).then(|| Echo {
            index,
            range_mm: range_mm.saturating_add(self.behind_mm).min(max_mm),
            intensity: intensity / 2,
        })
    }
}

/// CR is refused (status 04) by the UTM-30LX family, per the spec's note on CR and the real
/// UTM-30LX and UXM-30LX-E captures; older units such as the URG-04LX take it.
fn motor_speed_adjustable(model: &str) -> bool {
    !(model.starts_with("UTM-30LX") || model.starts_with("UXM-30LX"))
}

/// Bit rates SS accepts (bps).
const BIT_RATES: [u32; 8] = [
    19_200, 38_400, 57_600, 115_200, 250_000, 500_000, 750_000, 921_600,
];

impl Unit {
    pub fn new(info: &SensorInfo, geometry: ScanGeometry) -> Self {
        let field = |key: &str, default: &str| {
            (
                key.to_string(),
                info.fields
                    .get(key)
                    .cloned()
                    .unwrap_or_else(|| default.to_string()),
            )
        };
        let model = info
            .fields
            .get("MODL")
            .cloned()
            .unwrap_or_else(|| info.model.clone());
        let motor_speed_adjustable = motor_speed_adjustable(&model);
        Unit {
            geometry,
            version: vec![
                field("VEND", "Hokuyo Automatic Co.,Ltd."),
                field("PROD", &info.model),
                field("FIRM", "scanfuse-emulator"),
                field("PROT", "SCIP 2.0"),
                field("SERI", &info.id),
            ],
            model,
            fields: info.fields.clone(),
            mode: Mode::Idle,
            laser_on: false,
            high_sensitivity: false,
            motor_code: 0,
            motor_speed_adjustable,
            clock_zero_ms: 0,
            clock: ClockSetting::default(),
            synthetic_echoes: None,
            reboot_armed_at_ms: None,
            booting_until_ms: 0,
            streams_started: 0,
            reboots: 0,
            multi_echo: true,
        }
    }

    /// Makes the unit answer the multi-echo commands (ND NE HD HE) with `0E`, undefined
    /// command, as a unit without multi-echo does.
    pub fn without_multi_echo(mut self) -> Self {
        self.multi_echo = false;
        self
    }

    /// Reboots done so far; a change tells the server to drop the connection, as a real
    /// unit's restart does.
    pub fn reboots(&self) -> u64 {
        self.reboots
    }

    /// Makes the unit refuse TM0 and scans (status `10`) until host time `until_ms`, as a
    /// UTM-30LX-EW does while it boots.
    pub fn booting_until(mut self, until_ms: u64) -> Self {
        self.booting_until_ms = until_ms;
        self
    }

    pub fn geometry(&self) -> &ScanGeometry {
        &self.geometry
    }

    /// Sets where the sensor clock starts (at power-on and after each reset) and how fast
    /// it runs against the host's.
    pub fn with_clock(mut self, clock: ClockSetting) -> Self {
        self.clock = clock;
        self
    }

    /// Adds made-up further echoes to multi-echo scans (see [`SyntheticEchoes`]).
    pub fn with_synthetic_echoes(mut self, echoes: Option<SyntheticEchoes>) -> Self {
        self.synthetic_echoes = echoes;
        self
    }

    /// The sensor's 24-bit ms clock at host time `now_ms`.
    pub fn clock_ms(&self, now_ms: u64) -> u32 {
        let elapsed_ms = now_ms.saturating_sub(self.clock_zero_ms);
        let rate = 1.0 + self.clock.drift_ppm * 1e-6;
        let run_ms = if self.clock.drift_ppm == 0.0 {
            elapsed_ms
        } else {
            // Saturating float-to-int cast: a negative rate cannot wind the clock back.
            (elapsed_ms as f64 * rate).round() as u64
        };
        (self.clock.start_ms.wrapping_add(run_ms) & 0xFF_FFFF) as u32
    }

    pub fn state(&self) -> State {
        match (&self.mode, self.laser_on) {
            (Mode::TimeAdjust, _) => State::TimeAdjust,
            (Mode::Streaming(_), _) => State::MultiScan,
            (Mode::Idle, true) => State::SingleScan,
            (Mode::Idle, false) => State::Standby,
        }
    }

    pub fn is_streaming(&self) -> bool {
        matches!(self.mode, Mode::Streaming(_))
    }

    /// Streams started so far; a change tells the server to (re)start its scan timer.
    pub fn streams_started(&self) -> u64 {
        self.streams_started
    }

    fn reset(&mut self, now_ms: u64, keep_speed: bool) {
        self.mode = Mode::Idle;
        self.laser_on = false;
        self.high_sensitivity = false;
        if !keep_speed {
            self.motor_code = 0;
        }
        self.clock_zero_ms = now_ms;
    }

    /// Answers one command line (without LF/CR) at host time `now_ms`; `current` is the scan a
    /// GD/GE/GS/HD/HE returns.
    pub fn handle(&mut self, line: &[u8], now_ms: u64, current: Option<&SourceScan>) -> Vec<u8> {
        let request = match Request::parse(line) {
            Ok(request) => request,
            Err(err) => return encode_status(line, err.status()),
        };
        if !matches!(request.command, Command::Reboot) {
            self.reboot_armed_at_ms = None;
        }
        let ok = || encode_status(line, *b"00");
        if let Command::Scan(scan) = request.command
            && scan.kind.is_multi_echo()
            && !self.multi_echo
        {
            return encode_status(line, *b"0E");
        }
        if self.mode == Mode::TimeAdjust
            && !matches!(
                request.command,
                Command::Time(_)
                    | Command::Quit
                    | Command::Reset
                    | Command::ResetPartial
                    | Command::Reboot
                    | Command::Version
                    | Command::Info
                    | Command::SensorState
            )
        {
            // The unit takes no other command until TM2/QT (spec 8.6).
            return encode_status(line, *b"0A");
        }
        match request.command {
            Command::Version => encode_fields(
                line,
                self.version.iter().map(|(k, v)| (k.as_str(), v.as_str())),
            ),
            Command::Parameters => {
                let g = self.geometry.to_fields();
                let keys = ["DMIN", "DMAX", "ARES", "AMIN", "AMAX", "AFRT", "SCAN"];
                let mut fields = vec![("MODL", self.model.as_str())];
                fields.extend(keys.iter().filter_map(|k| Some((*k, g.get(*k)?.as_str()))));
                encode_fields(line, fields)
            }
            Command::Info => self.info_reply(line, now_ms),
            Command::SensorState => {
                let code: &[u8] = match self.state() {
                    State::Standby => b"000",
                    State::TimeAdjust => b"002",
                    State::SingleScan => b"003",
                    State::MultiScan => b"004",
                };
                let mut out = line.to_vec();
                out.push(b'\n');
                push_line(&mut out, b"00");
                push_line(&mut out, code);
                out.push(b'\n');
                out
            }
            Command::LaserOn => {
                if self.laser_on && !self.is_streaming() {
                    return encode_status(line, *b"02");
                }
                self.mode = Mode::Idle;
                self.laser_on = true;
                ok()
            }
            Command::Quit => {
                self.mode = Mode::Idle;
                self.laser_on = false;
                ok()
            }
            Command::Reset => {
                self.reset(now_ms, false);
                ok()
            }
            Command::ResetPartial => {
                self.reset(now_ms, true);
                ok()
            }
            Command::Reboot => match self.reboot_armed_at_ms {
                Some(at) if now_ms.saturating_sub(at) <= 1000 => {
                    self.reboot_armed_at_ms = None;
                    self.reset(now_ms, false);
                    self.reboots += 1;
                    ok()
                }
                _ => {
                    self.reboot_armed_at_ms = Some(now_ms);
                    encode_status(line, *b"01")
                }
            },
            Command::Time(TimeControl::Enter) | Command::Scan(_)
                if now_ms < self.booting_until_ms =>
            {
                encode_status(line, *b"10")
            }
            Command::Time(control) => self.time_reply(line, control, now_ms),
            Command::BitRate(bps) => {
                if BIT_RATES.contains(&bps) {
                    ok()
                } else {
                    encode_status(line, *b"01")
                }
            }
            // C-42-03320B 8.8: 04 = "incompatible with the current sensor model", which is what
            // the UTM-30LX and UXM-30LX-E captures answer to CR00; the URG-04LX answers 03
            // ("already running at that speed").
            Command::MotorSpeed(_) if !self.motor_speed_adjustable => encode_status(line, *b"04"),
            Command::MotorSpeed(code) => match code {
                c if c > 10 && c != 99 => encode_status(line, *b"02"),
                c if c == self.motor_code => encode_status(line, *b"03"),
                99 => {
                    self.motor_code = 0;
                    ok()
                }
                c => {
                    self.motor_code = c;
                    ok()
                }
            },
            Command::HighSensitivity(on) => {
                if on == self.high_sensitivity {
                    return encode_status(line, *b"02");
                }
                self.high_sensitivity = on;
                ok()
            }
            Command::Scan(scan) => self.scan_command(line, scan, now_ms, current),
        }
    }

    fn info_reply(&self, line: &[u8], now_ms: u64) -> Vec<u8> {
        let clock = self.clock_ms(now_ms);
        // Old firmwares print TIME as 6 hex digits, new ones SCIP-encode it; keep the recording's.
        let time = if self.fields.get("TIME").is_some_and(|t| t.len() == 6) {
            format!("{clock:06X}")
        } else {
            String::from_utf8_lossy(&encoding::encode(clock, 4)).into_owned()
        };
        let speed = format!("Initial({}[rpm])", self.geometry.scan_rpm);
        let mode = if self.is_streaming() {
            "Measuring".to_string()
        } else {
            self.fields
                .get("MESM")
                .cloned()
                .unwrap_or_else(|| "Idle".into())
        };
        let fields = [
            ("MODL", self.model.as_str()),
            (
                "LASR",
                if self.laser_on || self.is_streaming() {
                    "ON"
                } else {
                    "OFF"
                },
            ),
            ("SCSP", speed.as_str()),
            ("MESM", mode.as_str()),
            ("SBPS", "Ethernet 100[Mbps]"),
            ("TIME", time.as_str()),
            ("STAT", "Sensor works well."),
        ];
        encode_fields(line, fields)
    }

    fn time_reply(&mut self, line: &[u8], control: TimeControl, now_ms: u64) -> Vec<u8> {
        match (control, &self.mode) {
            (TimeControl::Enter, Mode::TimeAdjust) => encode_status(line, *b"02"),
            (TimeControl::Enter, _) => {
                self.mode = Mode::TimeAdjust;
                self.laser_on = false;
                encode_status(line, *b"00")
            }
            (TimeControl::Leave, Mode::TimeAdjust) => {
                self.mode = Mode::Idle;
                encode_status(line, *b"00")
            }
            (TimeControl::Leave, _) => encode_status(line, *b"03"),
            (TimeControl::Read, Mode::TimeAdjust) => {
                let mut out = line.to_vec();
                out.push(b'\n');
                push_line(&mut out, b"00");
                push_line(&mut out, &encoding::encode(self.clock_ms(now_ms), 4));
                out.push(b'\n');
                out
            }
            (TimeControl::Read, _) => encode_status(line, *b"04"),
        }
    }

    fn scan_command(
        &mut self,
        line: &[u8],
        scan: ScanRequest,
        now_ms: u64,
        current: Option<&SourceScan>,
    ) -> Vec<u8> {
        if scan.end_step as u32 > self.geometry.amax {
            return encode_status(line, *b"04");
        }
        if scan.continuous {
            self.laser_on = true;
            self.streams_started += 1;
            self.mode = Mode::Streaming(Stream {
                request: scan,
                line: line.to_vec(),
                remaining: (scan.scans > 0).then_some(scan.scans),
                skip: 0,
            });
            return encode_status(line, *b"00");
        }
        if !self.laser_on || self.is_streaming() {
            return encode_status(line, *b"10");
        }
        let Some(current) = current else {
            return encode_status(line, *b"10");
        };
        build(scan, current, self.clock_ms(now_ms), self.synthetic_echoes).encode(line, *b"00")
    }

    /// The next block of a running stream, or `None` when not streaming or when MD's scan
    /// interval skips this scan. Ends a finite stream after its last block.
    pub fn stream_block(&mut self, source: &SourceScan, now_ms: u64) -> Option<Vec<u8>> {
        let clock = self.clock_ms(now_ms);
        self.stream_block_stamped(source, clock)
    }

    /// [`Self::stream_block`] with the sensor clock reading given (a replay's recorded time).
    pub fn stream_block_stamped(&mut self, source: &SourceScan, clock: u32) -> Option<Vec<u8>> {
        let Mode::Streaming(stream) = &mut self.mode else {
            return None;
        };
        if stream.skip > 0 {
            stream.skip -= 1;
            return None;
        }
        stream.skip = stream.request.interval;
        let mut echo = stream.line.clone();
        let remaining = match stream.remaining.as_mut() {
            Some(r) => {
                *r = r.saturating_sub(1);
                *r
            }
            None => 0,
        };
        // The last two parameter digits (before any tag) count the scans still to come.
        if let Some(digits) = echo.get_mut(13..15) {
            digits.copy_from_slice(format!("{remaining:02}").as_bytes());
        }
        let block =
            build(stream.request, source, clock, self.synthetic_echoes).encode(&echo, *b"99");
        if stream.remaining == Some(0) {
            self.mode = Mode::Idle;
            self.laser_on = false;
        }
        Some(block)
    }
}

/// The values a scan command asks for: its steps, clustered (minimum valid range per cluster).
fn build(
    request: ScanRequest,
    source: &SourceScan,
    clock_ms: u32,
    synthetic: Option<SyntheticEchoes>,
) -> ScipScan {
    let cluster = request.cluster.max(1) as i64;
    let max = encoding::max_value(request.kind.range_width());
    let count = request.value_count();
    let mut ranges_mm = Vec::with_capacity(count);
    let mut extra_echoes = Vec::new();
    let mut intensities = Vec::with_capacity(if request.kind.has_intensity() {
        count
    } else {
        0
    });
    for v in 0..count as i64 {
        let first = request.start_step as i64 + v * cluster;
        let last = (first + cluster - 1).min(request.end_step as i64);
        let values: Vec<(u32, u32)> = (first..=last).map(|s| source.at(s)).collect();
        let pick = values
            .iter()
            .filter(|(r, _)| *r > 0)
            .min_by_key(|(r, _)| *r)
            .or(values.first());
        let (range, intensity) = pick.copied().unwrap_or((0, 0));
        ranges_mm.push(range.min(max));
        if request.kind.has_intensity() {
            intensities.push(intensity);
        }
        if let Some(synthetic) = synthetic.filter(|_| request.kind.is_multi_echo()) {
            let intensity = if request.kind.has_intensity() {
                intensity
            } else {
                0
            };
            extra_echoes.extend(synthetic.echo(v as u32, range.min(max), intensity, max));
        }
    }
    ScipScan {
        request,
        remaining: 0,
        timestamp_ms: clock_ms,
        ranges_mm,
        intensities,
        extra_echoes,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scip::{Framer, Reply, ScipScan, Status, info};

    fn unit() -> Unit {
        let mut info = SensorInfo::new("hall", "UTM-30LX-EW");
        info.fields.insert("MODL".into(), "UTM-30LX-EW".into());
        Unit::new(&info, ScanGeometry::UTM_30LX_EW)
    }

    fn source() -> SourceScan {
        SourceScan {
            first_step: 0,
            ranges_mm: (0..1081).map(|i| 1000 + i).collect(),
            intensities: vec![7; 1081],
        }
    }

    fn reply_of(bytes: &[u8]) -> crate::scip::Frame {
        let mut framer = Framer::new();
        framer.push(bytes);
        let frame = framer.next_frame().expect("one reply");
        assert_eq!(framer.pending(), 0, "exactly one reply");
        frame
    }

    #[test]
    fn time_adjust_mode_follows_the_spec() {
        let mut u = unit();
        assert_eq!(u.handle(b"TM1", 10, None), b"TM1\n04T\n\n");
        assert_eq!(u.handle(b"TM2", 10, None), b"TM2\n03S\n\n");
        assert_eq!(u.handle(b"TM0;x", 10, None), b"TM0;x\n00P\n\n");
        assert_eq!(u.handle(b"TM0", 10, None), b"TM0\n02R\n\n");
        assert_eq!(u.handle(b"BM", 10, None), b"BM\n0Aa\n\n");
        let frame = reply_of(&u.handle(b"TM1", 1234, None));
        assert_eq!(info::parse_tm1(&Reply::parse(&frame).unwrap()), Some(1234));
        // QT ends time-adjust mode, as on a UTM-30LX-EW.
        assert_eq!(u.handle(b"QT", 10, None), b"QT\n00P\n\n");
        assert_eq!(u.state(), State::Standby);
    }

    #[test]
    fn streams_count_down_and_echo_the_command_with_its_tag() {
        let mut u = unit();
        assert_eq!(
            u.handle(b"ME0000108001002;ab", 0, None),
            b"ME0000108001002;ab\n00P\n\n"
        );
        assert_eq!(u.state(), State::MultiScan);
        let first = u.stream_block(&source(), 5).unwrap();
        let frame = reply_of(&first);
        assert_eq!(frame.echo(), b"ME0000108001001;ab");
        let scan = ScipScan::decode(&Reply::parse(&frame).unwrap(), &mut Vec::new()).unwrap();
        assert_eq!(
            (scan.timestamp_ms, scan.ranges_mm[1080], scan.intensities[3]),
            (5, 2080, 7)
        );
        let second = reply_of(&u.stream_block(&source(), 30).unwrap());
        assert_eq!(second.echo(), b"ME0000108001000;ab");
        assert!(!u.is_streaming());
        assert_eq!(u.stream_block(&source(), 55), None);
    }

    #[test]
    fn bad_parameters_get_the_specs_status() {
        let mut u = unit();
        assert_eq!(
            u.handle(b"MD0000200001000", 0, None),
            b"MD0000200001000\n04T\n\n"
        );
        assert_eq!(
            u.handle(b"MD0500010001000", 0, None),
            b"MD0500010001000\n05U\n\n"
        );
        assert_eq!(
            u.handle(b"GD0000108001", 0, Some(&source())),
            b"GD0000108001\n10Q\n\n"
        );
        assert_eq!(u.handle(b"ZZ", 0, None), b"ZZ\n0Ee\n\n");
        assert_eq!(u.handle(b"BM", 0, None), b"BM\n00P\n\n");
        assert_eq!(u.handle(b"BM", 0, None), b"BM\n02R\n\n");
        assert_eq!(u.handle(b"RB", 0, None), b"RB\n01Q\n\n");
        assert_eq!(u.handle(b"RB", 500, None), b"RB\n00P\n\n");
        assert_eq!(u.clock_ms(600), 100);
    }

    #[test]
    fn a_unit_without_multi_echo_does_not_know_nd_ne_hd_he() {
        let mut u = unit().without_multi_echo();
        for line in [
            &b"ND0000108001000"[..],
            b"NE0000108001000",
            b"HD0000108001",
            b"HE0000108001",
        ] {
            let reply = reply_of(&u.handle(line, 0, Some(&source())));
            assert_eq!(Reply::parse(&reply).unwrap().status, Status(*b"0E"));
        }
        assert!(!u.is_streaming());
        assert_eq!(
            u.handle(b"MD0000108001000", 0, None),
            b"MD0000108001000\n00P\n\n"
        );
        assert_eq!(
            unit().handle(b"ND0000108001000", 0, None),
            b"ND0000108001000\n00P\n\n"
        );
    }

    #[test]
    fn a_second_rb_within_a_second_reboots_and_is_counted() {
        let mut u = unit();
        u.handle(b"RB", 0, None);
        u.handle(b"RB", 1500, None);
        assert_eq!(u.reboots(), 0, "too late: the second RB only arms again");
        u.handle(b"RB", 2000, None);
        assert_eq!(u.reboots(), 1);
    }

    #[test]
    fn clusters_keep_the_nearest_valid_range() {
        let mut u = unit();
        u.handle(b"BM", 0, None);
        let mut src = source();
        src.ranges_mm[1] = 0;
        let frame = reply_of(&u.handle(b"GD0000000903", 0, Some(&src)));
        let scan = ScipScan::decode(&Reply::parse(&frame).unwrap(), &mut Vec::new()).unwrap();
        assert_eq!(scan.ranges_mm, vec![1000, 1003, 1006, 1009]);
    }

    /// The host side of a real capture, replayed against a unit made from that capture's VV/PP
    /// answers: the same echoes, the same statuses (CR included: 04 on the UTM-30LX family,
    /// 03 on the URG-04LX), the same VV/PP fields and scans of the requested size.
    fn replay_capture(sent: &[u8], read: &[u8], model: &str, laser_was_on: bool) {
        use crate::scip::capture::unpack;
        use crate::scip::info::fields;
        let frames_of = |bytes: &[u8]| {
            let mut framer = Framer::new();
            framer.push(bytes);
            std::iter::from_fn(|| framer.next_frame()).collect::<Vec<_>>()
        };
        let real = frames_of(&unpack(read).unwrap());
        let field_map = |echo: &[u8]| {
            let frame = real.iter().find(|f| f.echo() == echo).unwrap();
            fields(&Reply::parse(frame).unwrap()).unwrap()
        };
        let mut info = SensorInfo::new("unit", model);
        info.fields = field_map(b"VV");
        info.fields.extend(field_map(b"PP"));
        assert!(info.fields["MODL"].starts_with(model), "{:?}", info.fields);
        let geometry = ScanGeometry::from_fields(&info.fields).unwrap();
        let mut unit = Unit::new(&info, geometry);
        if laser_was_on {
            // The capture starts with the laser on from an earlier session: its BM gets 02.
            unit.handle(b"BM", 0, None);
        }
        let src = SourceScan {
            first_step: 0,
            ranges_mm: vec![1234; geometry.amax as usize + 1],
            intensities: vec![99; geometry.amax as usize + 1],
        };
        let sent = unpack(sent).unwrap();
        let mut ours = Vec::new();
        for (i, line) in sent
            .split(|&b| b == b'\n')
            .filter(|l| !l.is_empty())
            .enumerate()
        {
            let now_ms = 1000 + 10 * i as u64;
            ours.extend(unit.handle(line, now_ms, Some(&src)));
            // A one-scan ME/MD stream sends its block after the acknowledgement.
            while let Some(block) = unit.stream_block(&src, now_ms + 5) {
                ours.extend(block);
            }
        }
        let ours = frames_of(&ours);
        assert_eq!(ours.len(), real.len());
        let mut scans = 0;
        for (a, b) in ours.iter().zip(&real) {
            assert_eq!(a.echo(), b.echo());
            let (ra, rb) = (Reply::parse(a).unwrap(), Reply::parse(b).unwrap());
            let echo = String::from_utf8_lossy(a.echo());
            assert_eq!(ra.status, rb.status, "{echo}");
            if a.echo() == b"VV" || a.echo() == b"PP" {
                assert_eq!(fields(&ra).unwrap(), fields(&rb).unwrap());
            }
            if rb.status == Status::SCAN_DATA
                || (a.echo().starts_with(b"G") && rb.lines().next().is_some())
            {
                let (sa, sb) = (
                    ScipScan::decode(&ra, &mut Vec::new()).unwrap(),
                    ScipScan::decode(&rb, &mut Vec::new()).unwrap(),
                );
                assert_eq!(sa.ranges_mm.len(), sb.ranges_mm.len(), "{echo}");
                assert_eq!(sa.intensities.len(), sb.intensities.len(), "{echo}");
                assert!(sa.ranges_mm.iter().all(|&r| r == 1234), "{echo}");
                scans += 1;
            }
        }
        assert_eq!(scans, 1, "each capture holds one scan");
    }

    #[test]
    fn replaying_the_uxm_30lx_e_session_gets_the_real_units_answers() {
        replay_capture(
            include_bytes!("../../fixtures/scip/example_uxm_30lx_e.logw"),
            include_bytes!("../../fixtures/scip/example_uxm_30lx_e.logr"),
            "UXM-30LX-E",
            false,
        );
    }

    #[test]
    fn replaying_the_utm_30lx_session_gets_the_real_units_answers() {
        replay_capture(
            include_bytes!("../../fixtures/scip/example_utm_30lx.logw"),
            include_bytes!("../../fixtures/scip/example_utm_30lx.logr"),
            "UTM-30LX",
            true,
        );
    }

    #[test]
    fn replaying_the_urg_04lx_session_gets_the_real_units_answers() {
        replay_capture(
            include_bytes!("../../fixtures/scip/example_urg_04lx.logw"),
            include_bytes!("../../fixtures/scip/example_urg_04lx.logr"),
            "URG-04LX",
            true,
        );
    }

    #[test]
    fn the_clock_starts_where_set_drifts_wraps_at_24_bits_and_restarts_on_reset() {
        let start_ms = (1 << 24) - 100;
        let mut u = unit().with_clock(ClockSetting {
            start_ms,
            drift_ppm: 1000.0,
        });
        assert_eq!(u.clock_ms(0), start_ms as u32);
        assert_eq!(u.clock_ms(50), start_ms as u32 + 50);
        // 1000 ppm fast: 10 s of host time are 10.01 s of sensor time, past the wrap.
        assert_eq!(u.clock_ms(10_000), (start_ms + 10_010 - (1 << 24)) as u32);
        assert_eq!(u.handle(b"RS", 20_000, None), b"RS\n00P\n\n");
        assert_eq!(u.clock_ms(20_000), start_ms as u32);
        assert_eq!(u.clock_ms(20_099), (1 << 24) - 1);
        assert_eq!(u.clock_ms(20_100), 0);
    }

    #[test]
    fn cr_is_refused_by_the_utm_family_and_checked_against_the_speed_elsewhere() {
        let mut utm = unit();
        assert_eq!(utm.handle(b"CR00", 0, None), b"CR00\n04T\n\n");
        assert_eq!(utm.handle(b"CR05", 0, None), b"CR05\n04T\n\n");
        let mut info = SensorInfo::new("old", "URG-04LX");
        info.fields
            .insert("MODL".into(), "URG-04LX(Hokuyo Automatic Co.,Ltd.)".into());
        let mut urg = Unit::new(&info, ScanGeometry::UTM_30LX_EW);
        assert_eq!(urg.handle(b"CR00", 0, None), b"CR00\n03S\n\n");
        assert_eq!(urg.handle(b"CR05", 0, None), b"CR05\n00P\n\n");
        assert_eq!(urg.handle(b"CR05", 0, None), b"CR05\n03S\n\n");
        assert_eq!(urg.handle(b"CR11", 0, None), b"CR11\n02R\n\n");
        assert_eq!(urg.handle(b"CR99", 0, None), b"CR99\n00P\n\n");
    }
}
