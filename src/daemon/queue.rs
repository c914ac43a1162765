//! The bounded queue between a sensor thread and the SLAM stage.
//!
//! Policy when full, per queue:
//!
//! - [`WhenFull::DropOldest`] (live drivers): a driver read is never
//!   blocked; the oldest waiting item is dropped to make room, counted, and
//!   the caller logs it. Dropping the oldest keeps what the stage sees as
//!   fresh as possible, and the bound caps the latency a backlog adds.
//! - [`WhenFull::Wait`] (replays): the reader waits for room, so a replay
//!   as fast as possible loses nothing and gives the same poses every time.
//!
//! A `Mutex<VecDeque>` and two condition variables: the items are a few
//! per millisecond, far below where a lock-free queue would matter, and
//! the policy needs "remove the oldest" from the producer's side, which
//! std's `sync_channel` does not offer.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Condvar, Mutex};
use std::time::{Duration, Instant};

/// What `push` does when the queue is full.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WhenFull {
    /// Drop the oldest waiting item to make room; the push never blocks (live drivers).
    DropOldest,
    /// Block until there is room (replays, so nothing is lost).
    Wait,
}

/// A bounded multi-producer queue with a stated overflow policy.
pub struct BoundedQueue<T> {
    name: &'static str,
    capacity: usize,
    when_full: WhenFull,
    items: Mutex<VecDeque<T>>,
    not_empty: Condvar,
    not_full: Condvar,
    dropped: AtomicU64,
    pushed: AtomicU64,
    closed: AtomicBool,
}

/// What happened to a pushed item.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pushed {
    /// Queued without dropping anything.
    Queued,
    /// Queued after the oldest item was dropped.
    DroppedOldest,
    /// The queue is closed; the item was discarded.
    Closed,
}

impl<T> BoundedQueue<T> {
    /// An empty queue named `name` (for logs and status) holding at most `capacity` items (at least
    /// 1), with the given overflow policy.
    pub fn new(name: &'static str, capacity: usize, when_full: WhenFull) -> Self {
        let capacity = capacity.max(1);
        Self {
            name,
            capacity,
            when_full,
            items: Mutex::new(VecDeque::with_capacity(capacity)),
            not_empty: Condvar::new(),
            not_full: Condvar::new(),
            dropped: AtomicU64::new(0),
            pushed: AtomicU64::new(0),
            closed: AtomicBool::new(false),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, VecDeque<T>> {
        // A panicking holder cannot leave the deque half-modified (push
        // and pop are single calls), so a poisoned lock is still usable.
        self.items.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Adds `item` by the queue's policy.
    pub fn push(&self, item: T) -> Pushed {
        let mut items = self.lock();
        let mut outcome = Pushed::Queued;
        loop {
            if self.closed.load(Ordering::Acquire) {
                return Pushed::Closed;
            }
            if items.len() < self.capacity {
                break;
            }
            match self.when_full {
                WhenFull::DropOldest => {
                    items.pop_front();
                    self.dropped.fetch_add(1, Ordering::Relaxed);
                    outcome = Pushed::DroppedOldest;
                    break;
                }
                WhenFull::Wait => {
                    items = self
                        .not_full
                        .wait_timeout(items, Duration::from_millis(100))
                        .unwrap_or_else(|e| e.into_inner())
                        .0;
                }
            }
        }
        items.push_back(item);
        self.pushed.fetch_add(1, Ordering::Relaxed);
        drop(items);
        self.not_empty.notify_one();
        outcome
    }

    /// The oldest item, waiting at most `timeout` for one.
    pub fn pop_timeout(&self, timeout: Duration) -> Option<T> {
        let deadline = Instant::now() + timeout;
        let mut items = self.lock();
        loop {
            if let Some(item) = items.pop_front() {
                drop(items);
                self.not_full.notify_one();
                return Some(item);
            }
            let now = Instant::now();
            if now >= deadline || self.closed.load(Ordering::Acquire) {
                return None;
            }
            items = self
                .not_empty
                .wait_timeout(items, deadline - now)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }

    /// The oldest item if one is waiting.
    pub fn try_pop(&self) -> Option<T> {
        let item = self.lock().pop_front();
        if item.is_some() {
            self.not_full.notify_one();
        }
        item
    }

    /// The oldest item's view without taking it.
    pub fn peek_with<R>(&self, f: impl FnOnce(Option<&T>) -> R) -> R {
        f(self.lock().front())
    }

    /// Wakes every waiter; later pushes are discarded, pops drain what is left.
    pub fn close(&self) {
        self.closed.store(true, Ordering::Release);
        self.not_empty.notify_all();
        self.not_full.notify_all();
    }

    /// Whether [`close`](Self::close) was called.
    pub fn is_closed(&self) -> bool {
        self.closed.load(Ordering::Acquire)
    }

    /// Items waiting now.
    pub fn len(&self) -> usize {
        self.lock().len()
    }

    /// Whether no item is waiting now.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Largest number of waiting items.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// The name given at construction, for logs and status.
    pub fn name(&self) -> &'static str {
        self.name
    }

    /// Items dropped by the policy since start.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Items accepted since start.
    pub fn pushed(&self) -> u64 {
        self.pushed.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn drop_oldest_keeps_the_newest_and_counts() {
        let q = BoundedQueue::new("t", 3, WhenFull::DropOldest);
        for i in 0..5 {
            let outcome = q.push(i);
            assert_eq!(outcome == Pushed::DroppedOldest, i >= 3);
        }
        assert_eq!(q.dropped(), 2);
        let got: Vec<i32> = std::iter::from_fn(|| q.try_pop()).collect();
        assert_eq!(got, vec![2, 3, 4]);
    }

    #[test]
    fn wait_loses_nothing() {
        let q = Arc::new(BoundedQueue::new("t", 2, WhenFull::Wait));
        let producer = {
            let q = q.clone();
            std::thread::spawn(move || {
                for i in 0..1000 {
                    q.push(i);
                }
            })
        };
        let mut got = Vec::new();
        while got.len() < 1000 {
            if let Some(i) = q.pop_timeout(Duration::from_secs(5)) {
                got.push(i);
            } else {
                break;
            }
        }
        producer.join().expect("producer");
        assert_eq!(got, (0..1000).collect::<Vec<_>>());
        assert_eq!(q.dropped(), 0);
    }

    #[test]
    fn close_wakes_a_waiting_consumer_and_refuses_pushes() {
        let q = Arc::new(BoundedQueue::<u8>::new("t", 2, WhenFull::Wait));
        let consumer = {
            let q = q.clone();
            std::thread::spawn(move || q.pop_timeout(Duration::from_secs(30)))
        };
        std::thread::sleep(Duration::from_millis(20));
        q.close();
        assert_eq!(consumer.join().expect("consumer"), None);
        assert_eq!(q.push(1), Pushed::Closed);
    }
}
