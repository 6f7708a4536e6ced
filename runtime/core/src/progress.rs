//! Progress of long work, reported to whoever drives it. Libraries take a
//! `&dyn Progress` and never draw: the binary supplies a terminal bar, tests
//! and embedders [`Silent`].

/// A counter of finished steps out of a total, and the console of a
/// long-running service.
pub trait Progress: Send + Sync + std::fmt::Debug {
    /// Starts a phase of `total` steps named `what` (0: open-ended).
    fn start(&self, what: &str, total: u64);
    /// `n` more steps are done.
    fn advance(&self, n: u64);
    /// The phase is over.
    fn finish(&self);
    /// Replaces the live status line of an open-ended phase.
    fn status(&self, _line: &str) {}
    /// Shows a block of text now (a table asked for by a signal).
    fn note(&self, _text: &str) {}
}

/// Reports nothing.
#[derive(Debug, Default, Clone, Copy)]
pub struct Silent;

impl Progress for Silent {
    fn start(&self, _: &str, _: u64) {}
    fn advance(&self, _: u64) {}
    fn finish(&self) {}
}
