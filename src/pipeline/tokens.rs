//! Memory tokens: the tile memory of the budget is cut into one share per worker, and a
//! worker holds one token per share its tile needs. A tile too big for one share but within
//! the whole tile memory takes several tokens and runs while the other workers wait, instead
//! of failing the run (or being split into slivers whose contexts repeat the same points).
//!
//! Takers are served first come, first served: a worker that gives its token back and asks
//! again at once queues behind one waiting for several, so a big tile is never starved.

use std::sync::{Condvar, Mutex, MutexGuard};

/// The tokens of one run.
pub(super) struct MemoryTokens {
    state: Mutex<State>,
    cv: Condvar,
    total: usize,
}

struct State {
    free: usize,
    /// Next ticket to hand out / ticket being served.
    next: u64,
    serving: u64,
}

impl MemoryTokens {
    /// `total` tokens (the workers' shares), all free.
    pub fn new(total: usize) -> Self {
        MemoryTokens {
            state: Mutex::new(State {
                free: total.max(1),
                next: 0,
                serving: 0,
            }),
            cv: Condvar::new(),
            total: total.max(1),
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // A poisoned lock only means another worker panicked; the counts stay consistent
        // because every update is a single statement.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Takes `n` tokens (at most all), waiting for them in turn.
    pub fn take(&self, n: usize) {
        let n = n.clamp(1, self.total);
        let mut s = self.lock();
        let me = s.next;
        s.next += 1;
        while s.serving != me || s.free < n {
            s = self.cv.wait(s).unwrap_or_else(|e| e.into_inner());
        }
        s.free -= n;
        s.serving += 1;
        drop(s);
        self.cv.notify_all();
    }

    /// Gives `n` tokens back.
    pub fn give(&self, n: usize) {
        if n == 0 {
            return;
        }
        let mut s = self.lock();
        s.free = (s.free + n).min(self.total);
        drop(s);
        self.cv.notify_all();
    }

    /// Whether a worker is waiting for tokens.
    pub fn contended(&self) -> bool {
        let s = self.lock();
        s.next != s.serving
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    #[test]
    fn never_more_than_total_in_use_and_big_takers_are_served() {
        let t = MemoryTokens::new(2);
        let in_use = AtomicUsize::new(0);
        let max = AtomicUsize::new(0);
        let big_done = AtomicUsize::new(0);
        std::thread::scope(|s| {
            for w in 0..3 {
                let (t, in_use, max, big_done) = (&t, &in_use, &max, &big_done);
                s.spawn(move || {
                    for i in 0..200 {
                        let n = if w == 0 && i % 10 == 0 { 2 } else { 1 };
                        t.take(n);
                        let now = in_use.fetch_add(n, Ordering::SeqCst) + n;
                        max.fetch_max(now, Ordering::SeqCst);
                        std::thread::yield_now();
                        in_use.fetch_sub(n, Ordering::SeqCst);
                        t.give(n);
                        if n == 2 {
                            big_done.fetch_add(1, Ordering::SeqCst);
                        }
                    }
                });
            }
        });
        assert!(max.load(Ordering::SeqCst) <= 2);
        assert_eq!(big_done.load(Ordering::SeqCst), 20);
        assert!(!t.contended());
    }
}
