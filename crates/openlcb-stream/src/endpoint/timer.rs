//! Per-stream timers in a fixed table: an enum indexes an array of deadlines.

use crate::{Duration, Instant};

/// The waits a stream can have running.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Timer {
    /// Source: Initiate Reply.
    Reply = 0,
    /// Source: a Proceed while out of credit.
    Proceed = 1,
    /// Source: time to send a keep-alive.
    Keepalive = 2,
    /// Destination: the source's silence while holding credit.
    Idle = 3,
    /// Destination: the application's accept or reject.
    Decision = 4,
}

impl Timer {
    pub(crate) const ALL: [Timer; 5] = [Timer::Reply, Timer::Proceed, Timer::Keepalive, Timer::Idle, Timer::Decision];
}

/// One optional deadline per [`Timer`]. A spurious expiry check is harmless.
#[derive(Debug, Clone, Default)]
pub(crate) struct TimerTable([Option<Instant>; 5]);

impl TimerTable {
    /// Runs `timer` out `after` from `now` (one place for the saturating 64-bit add).
    #[inline(never)]
    pub(crate) fn start(&mut self, timer: Timer, now: Instant, after: Duration) {
        self.set(timer, now + after);
    }

    pub(crate) fn set(&mut self, timer: Timer, at: Instant) {
        if let Some(slot) = self.0.get_mut(timer as usize) {
            *slot = Some(at);
        }
    }

    pub(crate) fn stop(&mut self, timer: Timer) {
        if let Some(slot) = self.0.get_mut(timer as usize) {
            *slot = None;
        }
    }

    pub(crate) fn stop_all(&mut self) {
        self.0 = [None; 5];
    }

    /// The earliest deadline.
    pub(crate) fn next(&self) -> Option<Instant> {
        self.0.iter().flatten().min().copied()
    }

    /// Removes and returns the first timer due at `now`.
    pub(crate) fn take_expired(&mut self, now: Instant) -> Option<Timer> {
        let timer =
            Timer::ALL.into_iter().find(|t| self.0.get(*t as usize).copied().flatten().is_some_and(|at| at <= now))?;
        self.stop(timer);
        Some(timer)
    }
}
