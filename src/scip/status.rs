//! Reply status codes: `00` (done) and `99` (scan data follow) are success; everything else is
//! an error whose meaning depends on the command, kept together with its raw two characters.

use thiserror::Error;

/// The two status characters of a reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Status(pub [u8; 2]);

impl Status {
    pub const OK: Status = Status(*b"00");
    pub const SCAN_DATA: Status = Status(*b"99");

    /// `00` or `99`.
    pub fn is_success(self) -> bool {
        self == Self::OK || self == Self::SCAN_DATA
    }

    /// The status as text, e.g. `"0E"`.
    pub fn as_str(&self) -> String {
        String::from_utf8_lossy(&self.0).into_owned()
    }

    /// `Ok` for success, else the typed error for a reply to `command` (two letters).
    pub fn check(self, command: [u8; 2]) -> Result<(), StatusError> {
        if self.is_success() {
            return Ok(());
        }
        Err(StatusError {
            command,
            code: self.0,
            kind: StatusKind::classify(command, self.0),
        })
    }
}

/// What a non-success status means, as far as the spec says (p. 11, 13–23).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum StatusKind {
    /// 01–07 on scan commands, 01 on others: a parameter was not a number or out of range.
    BadParameter,
    /// `02` on BM/HS/TM0, `03` on TM2: the sensor is already in the requested state.
    AlreadyInState,
    /// `04` on TM1: time requested outside time-adjust mode.
    NotInTimeAdjust,
    /// `10` on GD/GE/…: the laser is off (send BM first).
    LaserOff,
    /// 21–49: processing stopped to check an error.
    Stopped,
    /// 50–97: hardware trouble (laser, motor).
    Hardware,
    /// 98: resumed after the laser was confirmed working.
    Resumed,
    /// 0A/0B: the sensor could not build the reply, or the command was repeated.
    Busy,
    /// 0C/0F: too few parameters.
    InsufficientParameters,
    /// 0D/0E: the sensor does not know the command.
    UndefinedCommand,
    /// 0G/0H: the `;tag` is longer than 16 characters or has invalid characters.
    BadTag,
    /// 0I: firmware update mode.
    FirmwareUpdate,
    /// 0L: the sensor is in an abnormal state (a fault it cannot clear itself); reference
    /// drivers reboot it (RB twice).
    Abnormal,
    /// Anything else, e.g. a command-specific refusal (`CR` 03/04).
    Other,
}

impl StatusKind {
    fn classify(command: [u8; 2], code: [u8; 2]) -> StatusKind {
        match (&command, &code) {
            (_, b"0A" | b"0B") => StatusKind::Busy,
            (_, b"0C" | b"0F") => StatusKind::InsufficientParameters,
            (_, b"0D" | b"0E") => StatusKind::UndefinedCommand,
            (_, b"0G" | b"0H") => StatusKind::BadTag,
            (_, b"0I") => StatusKind::FirmwareUpdate,
            (_, b"0L") => StatusKind::Abnormal,
            (b"BM" | b"HS", b"02") => StatusKind::AlreadyInState,
            (b"TM", b"02" | b"03") => StatusKind::AlreadyInState,
            (b"TM", b"04") => StatusKind::NotInTimeAdjust,
            (b"TM", b"01") => StatusKind::BadParameter,
            (_, b"10") => StatusKind::LaserOff,
            (_, b"98") => StatusKind::Resumed,
            (b"MD" | b"MS" | b"ME" | b"ND" | b"NE" | b"GD" | b"GS" | b"GE" | b"HD" | b"HE", _)
                if (b"01"..=b"07").contains(&&code) =>
            {
                StatusKind::BadParameter
            }
            (_, b"01") => StatusKind::BadParameter,
            _ => match std::str::from_utf8(&code)
                .ok()
                .and_then(|s| s.parse::<u8>().ok())
            {
                Some(21..=49) => StatusKind::Stopped,
                Some(50..=97) => StatusKind::Hardware,
                _ => StatusKind::Other,
            },
        }
    }
}

impl StatusKind {
    /// The state or refusal by name, as a person reads it in a log or on the status socket;
    /// `None` for [`StatusKind::Other`], whose meaning depends on the command.
    pub fn name(self) -> Option<&'static str> {
        Some(match self {
            StatusKind::BadParameter => "bad parameter",
            StatusKind::AlreadyInState => "already in that state",
            StatusKind::NotInTimeAdjust => "not in time-adjust mode",
            StatusKind::LaserOff => "laser off",
            StatusKind::Stopped => "stopped to check an error",
            StatusKind::Hardware => "hardware trouble",
            StatusKind::Resumed => "resumed",
            StatusKind::Busy => "busy",
            StatusKind::InsufficientParameters => "too few parameters",
            StatusKind::UndefinedCommand => "undefined command",
            StatusKind::BadTag => "bad tag",
            StatusKind::FirmwareUpdate => "firmware update mode",
            StatusKind::Abnormal => "abnormal state",
            StatusKind::Other => return None,
        })
    }
}

/// A sensor refused a command; names the command and keeps the raw status. Reads e.g.
/// "sensor answered RS with abnormal state (0L)", or "… with status 04" when the code has no
/// name of its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Error)]
pub struct StatusError {
    pub command: [u8; 2],
    pub code: [u8; 2],
    pub kind: StatusKind,
}

impl StatusError {
    /// The status alone: "abnormal state (0L)", or "status 04" when it has no name.
    pub fn status_text(&self) -> String {
        let code = String::from_utf8_lossy(&self.code);
        match self.kind.name() {
            Some(name) => format!("{name} ({code})"),
            None => format!("status {code}"),
        }
    }
}

impl std::fmt::Display for StatusError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let command = String::from_utf8_lossy(&self.command);
        write!(f, "sensor answered {command} with {}", self.status_text())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_are_classified_per_command_and_keep_the_raw_code() {
        let err = Status(*b"02").check(*b"BM").unwrap_err();
        assert_eq!(err.kind, StatusKind::AlreadyInState);
        assert_eq!(&err.code, b"02");
        assert_eq!(
            Status(*b"04").check(*b"TM").unwrap_err().kind,
            StatusKind::NotInTimeAdjust
        );
        assert_eq!(
            Status(*b"05").check(*b"MD").unwrap_err().kind,
            StatusKind::BadParameter
        );
        assert_eq!(
            Status(*b"0E").check(*b"XX").unwrap_err().kind,
            StatusKind::UndefinedCommand
        );
        assert_eq!(
            Status(*b"55").check(*b"MD").unwrap_err().kind,
            StatusKind::Hardware
        );
        assert_eq!(
            Status(*b"04").check(*b"CR").unwrap_err().kind,
            StatusKind::Other
        );
        assert!(Status(*b"99").check(*b"MD").is_ok());
        assert!(err.to_string().contains("BM") && err.to_string().contains("02"));
    }

    #[test]
    fn an_abnormal_state_is_named_not_other() {
        let err = Status(*b"0L").check(*b"RS").unwrap_err();
        assert_eq!(err.kind, StatusKind::Abnormal);
        assert_eq!(
            err.to_string(),
            "sensor answered RS with abnormal state (0L)"
        );
        assert_eq!(
            Status(*b"10").check(*b"TM").unwrap_err().to_string(),
            "sensor answered TM with laser off (10)"
        );
        assert_eq!(
            Status(*b"04").check(*b"CR").unwrap_err().to_string(),
            "sensor answered CR with status 04"
        );
    }
}
