//! Failures the emulator can inject, and what it did, for tests to compare with a driver's
//! counters.

use std::time::Duration;

/// Faults to inject; all off by default. Counts are over all connections.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Faults {
    /// Close the connection right after this many scans (once).
    pub drop_after_scans: Option<u64>,
    /// Flip one checksum in every Nth scan block.
    pub corrupt_every: Option<u64>,
    /// After this many scans, send nothing for this long, connection open (once).
    pub stall: Option<(u64, Duration)>,
    /// Send junk bytes before every Nth scan block.
    pub garbage_every: Option<u64>,
    /// Close every connection at once for this long after the emulator starts.
    pub refuse_for: Option<Duration>,
    /// Refuse TM0 and scan commands (status `10`) for this long after the emulator starts,
    /// like a unit still booting.
    pub booting_for: Option<Duration>,
    /// Answer `0L` (abnormal state) to every command but RB, QT, VV, PP and II until rebooted
    /// (RB twice) this many times; `u32::MAX` never recovers. Each reboot drops the
    /// connection, as a real unit's restart does.
    pub abnormal_until_reboots: Option<u32>,
    /// Answer `0E` (undefined command) to the multi-echo commands ND NE HD HE, like a unit
    /// without multi-echo (UTM-30LX).
    pub no_multi_echo: bool,
    /// Every range of every scan is 0 (no return), like a unit with a covered window.
    pub no_returns: bool,
}

/// Junk of the kind a half-read reply or line noise leaves behind.
pub const GARBAGE: &[u8] = b"\x00\xff#?\x13garbage\n\nQ\n";

/// What the emulator did, over all connections.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct EmulatorStats {
    pub connections: u64,
    pub refused: u64,
    pub scans_sent: u64,
    pub corrupted: u64,
    pub garbage_bursts: u64,
    pub dropped: u64,
    pub stalls: u64,
    /// QT commands received (clients stopping the laser).
    pub quits: u64,
    /// Connections the client ended (end of stream), as opposed to a fault or an error.
    pub client_closes: u64,
    /// Reboots (RB twice), each ending its connection.
    pub reboots: u64,
    /// Commands answered `0L` (abnormal state).
    pub abnormal_answers: u64,
}
