//! The bounded queue from the sensor tasks to the registration worker: when it is full the
//! oldest item is dropped and counted, so a slow registration never stalls a sensor.

use std::ops::Deref;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use crossbeam_channel::{Receiver, Sender, TryRecvError, TrySendError, bounded};

/// The worker has gone away; nothing will read the queue again.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("the registration worker has stopped")]
pub struct WorkerGone;

/// The producers' end. Cheap to clone, one per sensor task.
#[derive(Debug, Clone)]
pub struct DropOldestSender<T> {
    tx: Sender<T>,
    /// Kept only to take the oldest item out when the queue is full.
    rx: Receiver<T>,
    drops: Arc<AtomicU64>,
    /// Set when the worker's end is dropped (the producers' receiver clone keeps the channel
    /// itself open, so crossbeam cannot tell them).
    closed: Arc<AtomicBool>,
}

/// The worker's end: a crossbeam [`Receiver`] (through `Deref`) that tells the producers when
/// it is dropped.
#[derive(Debug)]
pub struct WorkerEnd<T> {
    rx: Receiver<T>,
    closed: Arc<AtomicBool>,
}

impl<T> Deref for WorkerEnd<T> {
    type Target = Receiver<T>;
    fn deref(&self) -> &Receiver<T> {
        &self.rx
    }
}

impl<T> Drop for WorkerEnd<T> {
    fn drop(&mut self) {
        self.closed.store(true, Ordering::Release);
    }
}

/// A queue of `capacity` items: the producers' end and the worker's end.
pub fn drop_oldest<T>(capacity: usize) -> (DropOldestSender<T>, WorkerEnd<T>) {
    let (tx, rx) = bounded(capacity.max(1));
    let closed = Arc::new(AtomicBool::new(false));
    let sender = DropOldestSender {
        tx,
        rx: rx.clone(),
        drops: Arc::new(AtomicU64::new(0)),
        closed: Arc::clone(&closed),
    };
    (sender, WorkerEnd { rx, closed })
}

impl<T> DropOldestSender<T> {
    /// Queues `item`, dropping the oldest queued item if the queue is full. Never blocks.
    pub fn push(&self, mut item: T) -> Result<(), WorkerGone> {
        if self.closed.load(Ordering::Acquire) {
            return Err(WorkerGone);
        }
        loop {
            match self.tx.try_send(item) {
                Ok(()) => return Ok(()),
                Err(TrySendError::Full(back)) => {
                    item = back;
                    // Another producer or the worker may have emptied a slot meanwhile: only
                    // count what this call actually removed.
                    match self.rx.try_recv() {
                        Ok(_) => {
                            self.drops.fetch_add(1, Ordering::Relaxed);
                        }
                        Err(TryRecvError::Empty) => {}
                        Err(TryRecvError::Disconnected) => return Err(WorkerGone),
                    }
                }
                Err(TrySendError::Disconnected(_)) => return Err(WorkerGone),
            }
        }
    }

    /// Items dropped so far, by every producer.
    pub fn drops(&self) -> u64 {
        self.drops.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_queue_drops_the_oldest_and_counts() {
        let (tx, rx) = drop_oldest(3);
        for i in 0..5 {
            tx.push(i).unwrap();
        }
        assert_eq!(tx.drops(), 2);
        let left: Vec<i32> = rx.try_iter().collect();
        assert_eq!(left, vec![2, 3, 4]);
    }

    #[test]
    fn producers_never_block_and_nothing_is_lost_uncounted() {
        let (tx, rx) = drop_oldest::<u64>(16);
        let producers: Vec<_> = (0..4)
            .map(|p| {
                let tx = tx.clone();
                std::thread::spawn(move || {
                    for i in 0..10_000 {
                        tx.push(p * 1_000_000 + i).unwrap();
                    }
                })
            })
            .collect();
        // A slow worker, which stops once the producers are done and the queue is empty.
        let done = Arc::new(AtomicBool::new(false));
        let finished = Arc::clone(&done);
        let worker = std::thread::spawn(move || {
            let mut got = 0u64;
            loop {
                match rx.recv_timeout(std::time::Duration::from_millis(10)) {
                    Ok(_item) => {
                        got += 1;
                        if got.is_multiple_of(10) {
                            std::thread::sleep(std::time::Duration::from_micros(50));
                        }
                    }
                    Err(_) if finished.load(Ordering::Acquire) => return got,
                    Err(_) => {}
                }
            }
        });
        for p in producers {
            p.join().unwrap();
        }
        done.store(true, Ordering::Release);
        let got = worker.join().unwrap();
        assert_eq!(
            got + tx.drops(),
            40_000,
            "every item was either received or counted"
        );
        assert!(tx.drops() > 0);
    }

    #[test]
    fn a_stopped_worker_is_reported() {
        let (tx, rx) = drop_oldest::<u8>(2);
        tx.push(1).unwrap();
        drop(rx);
        assert_eq!(tx.push(2), Err(WorkerGone));
        assert_eq!(tx.clone().push(3), Err(WorkerGone));
    }
}
