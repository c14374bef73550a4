//! The run's shared failure state: the first real error wins (an [`Error::Cancelled`] only
//! until a real one arrives); every other thread stops quietly when it sees the flag.

use crate::error::Error;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;

/// Shared by the reader, the tiler, the workers and the writer of one run.
#[derive(Default)]
pub(super) struct Failure {
    first: Mutex<Option<Error>>,
    flag: AtomicBool,
}

impl Failure {
    /// Records `e` (unless a real error is already recorded) and raises the flag.
    pub fn set(&self, e: Error) {
        let mut g = self.first.lock().unwrap_or_else(|p| p.into_inner());
        let replace = match &*g {
            None => true,
            Some(Error::Cancelled) => !matches!(e, Error::Cancelled),
            Some(_) => false,
        };
        if replace {
            *g = Some(e);
        }
        self.flag.store(true, Ordering::SeqCst);
    }

    /// Whether any part of the run failed.
    pub fn failed(&self) -> bool {
        self.flag.load(Ordering::SeqCst)
    }

    /// The error that ended the run, if any.
    pub fn into_error(self) -> Option<Error> {
        self.first.into_inner().unwrap_or_else(|p| p.into_inner())
    }
}
