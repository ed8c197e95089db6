//! Progress reporting hook, so the library stays free of terminal UI.

/// Receives work units as they finish; called from worker threads.
pub trait Progress: Sync {
    fn start(&self, _stage: &str, _total: u64) {}
    fn advance(&self, _n: u64) {}
}

/// Ignores progress.
pub struct NoProgress;
impl Progress for NoProgress {}
