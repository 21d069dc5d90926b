//! Thread priority. The live path (drivers, the socket, the tracker) answers within
//! milliseconds; registration and the map's grid are background work that can hold a core for
//! 100 ms at a time (at 100 sensors `perf sched` showed a registration pass holding one core
//! for 132 ms while the drivers, the socket and the tracker queued on the other), so on a
//! small machine they run at a lower priority and give way when the live path wakes.

/// How far background threads lower their priority (nice steps above the daemon's own).
pub const BACKGROUND_NICE_STEPS: i32 = 10;

/// Lowers the calling thread's priority by [`BACKGROUND_NICE_STEPS`]. Where the system does
/// not allow it the thread runs on at the daemon's priority: slower answers, nothing lost.
pub fn lower_this_thread() {
    let tid = Some(rustix::thread::gettid());
    let result = rustix::process::getpriority_process(tid).and_then(|now| {
        rustix::process::setpriority_process(tid, (now + BACKGROUND_NICE_STEPS).min(19))
    });
    if let Err(e) = result {
        tracing::debug!("could not lower this thread's priority: {e}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_background_thread_runs_at_a_lower_priority_than_the_one_that_started_it() {
        let own = rustix::process::getpriority_process(Some(rustix::thread::gettid()))
            .expect("own priority");
        let lowered = std::thread::spawn(|| {
            lower_this_thread();
            rustix::process::getpriority_process(Some(rustix::thread::gettid()))
                .expect("the thread's priority")
        })
        .join()
        .expect("the thread ends");
        assert_eq!(lowered, (own + BACKGROUND_NICE_STEPS).min(19));
        let after = rustix::process::getpriority_process(Some(rustix::thread::gettid()))
            .expect("own priority");
        assert_eq!(after, own, "only the background thread gave way");
    }
}
