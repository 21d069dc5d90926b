//! A driver's counters. Readers take snapshots; nothing ever resets them, so a slow status
//! client sees totals, not "since I last asked".

use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

#[derive(Debug, Default)]
pub struct Counters {
    pub connects: AtomicU64,
    pub reconnects: AtomicU64,
    /// Connection attempts that failed (refused, timed out, no such port).
    pub connect_failures: AtomicU64,
    pub scans: AtomicU64,
    pub checksum_errors: AtomicU64,
    pub status_errors: AtomicU64,
    pub decode_errors: AtomicU64,
    pub skipped_bytes: AtomicU64,
    pub watchdog_timeouts: AtomicU64,
    pub time_syncs: AtomicU64,
    /// Scans the consumer was too slow to take.
    pub dropped_scans: AtomicU64,
    last_error: Mutex<Option<String>>,
}

/// The counters at one moment.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct CounterSnapshot {
    pub connects: u64,
    pub reconnects: u64,
    pub connect_failures: u64,
    pub scans: u64,
    pub checksum_errors: u64,
    pub status_errors: u64,
    pub decode_errors: u64,
    pub skipped_bytes: u64,
    pub watchdog_timeouts: u64,
    pub time_syncs: u64,
    pub dropped_scans: u64,
    pub last_error: Option<String>,
}

impl Counters {
    pub fn add(counter: &AtomicU64, n: u64) {
        counter.fetch_add(n, Ordering::Relaxed);
    }

    pub fn set_last_error(&self, error: String) {
        *self.last_error.lock().unwrap_or_else(|e| e.into_inner()) = Some(error);
    }

    pub fn snapshot(&self) -> CounterSnapshot {
        let get = |c: &AtomicU64| c.load(Ordering::Relaxed);
        CounterSnapshot {
            connects: get(&self.connects),
            reconnects: get(&self.reconnects),
            connect_failures: get(&self.connect_failures),
            scans: get(&self.scans),
            checksum_errors: get(&self.checksum_errors),
            status_errors: get(&self.status_errors),
            decode_errors: get(&self.decode_errors),
            skipped_bytes: get(&self.skipped_bytes),
            watchdog_timeouts: get(&self.watchdog_timeouts),
            time_syncs: get(&self.time_syncs),
            dropped_scans: get(&self.dropped_scans),
            last_error: self
                .last_error
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .clone(),
        }
    }
}
