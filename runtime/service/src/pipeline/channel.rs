//! Newest-wins hand-over between stage threads: a bounded crossbeam
//! channel whose sender, when the channel is full, takes out the oldest
//! waiting frame (counted as dropped) instead of waiting. A slow stage thus
//! always works on the newest frame, and no producer ever blocks on it.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use crossbeam_channel::{Receiver, Sender, TrySendError, bounded};

/// The sending end of a newest-wins channel.
#[derive(Debug)]
pub struct NewestSender<T> {
    tx: Sender<T>,
    /// Kept to evict the oldest item; it does not keep receivers alive.
    evict: Receiver<T>,
    dropped: Arc<AtomicU64>,
}

impl<T> Clone for NewestSender<T> {
    fn clone(&self) -> Self {
        Self {
            tx: self.tx.clone(),
            evict: self.evict.clone(),
            dropped: self.dropped.clone(),
        }
    }
}

/// A channel holding at most `capacity` items; `dropped` counts evictions.
pub fn newest_channel<T>(
    capacity: usize,
    dropped: Arc<AtomicU64>,
) -> (NewestSender<T>, Receiver<T>) {
    let (tx, rx) = bounded(capacity.max(1));
    (
        NewestSender {
            tx,
            evict: rx.clone(),
            dropped,
        },
        rx,
    )
}

impl<T> NewestSender<T> {
    /// Sends `item`, evicting the oldest waiting item if the channel is full.
    pub fn send(&self, mut item: T) {
        loop {
            match self.tx.try_send(item) {
                Ok(()) => return,
                Err(TrySendError::Full(back)) => {
                    if self.evict.try_recv().is_ok() {
                        self.dropped.fetch_add(1, Ordering::Relaxed);
                    }
                    item = back;
                }
                // Unreachable while `evict` lives; nothing to deliver to.
                Err(TrySendError::Disconnected(_)) => return,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_full_channel_keeps_the_newest_and_counts_the_rest() {
        let dropped = Arc::new(AtomicU64::new(0));
        let (tx, rx) = newest_channel(2, dropped.clone());
        for i in 0..5 {
            tx.send(i);
        }
        assert_eq!(rx.try_iter().collect::<Vec<_>>(), vec![3, 4]);
        assert_eq!(dropped.load(Ordering::Relaxed), 3);
        drop(tx);
        assert!(
            matches!(
                rx.recv_timeout(crate::deadline::THREAD),
                Err(crossbeam_channel::RecvTimeoutError::Disconnected)
            ),
            "dropping every sender ends the stream"
        );
    }

    #[test]
    fn a_slow_consumer_loses_only_counted_items_and_never_the_last() {
        let dropped = Arc::new(AtomicU64::new(0));
        let (tx, rx) = newest_channel(1, dropped.clone());
        let consumer = std::thread::spawn(move || {
            let mut got = Vec::new();
            for v in rx {
                got.push(v);
                std::thread::yield_now();
            }
            got
        });
        for i in 0..20_000u32 {
            tx.send(i);
        }
        drop(tx);
        let got = crate::deadline::join_within(
            consumer,
            crate::deadline::THREAD,
            "the consumer to take every item",
        );
        assert!(got.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(got.last(), Some(&19_999));
        assert_eq!(got.len() as u64 + dropped.load(Ordering::Relaxed), 20_000);
    }
}
