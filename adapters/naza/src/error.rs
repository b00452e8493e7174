//! The crate's errors.

use rove_core::MonoTime;
use rove_core::error::LinkError;

/// Result alias for `rove-naza`.
pub type Result<T, E = NazaError> = std::result::Result<T, E>;

/// Why a motor command was not carried out.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NazaError {
    /// A CSC is already being held; wait until `until` (the operator pressed twice, or start
    /// and stop overlapped).
    #[error("a combination stick command is already in progress until {until}")]
    CscInProgress {
        /// When the current CSC ends.
        until: MonoTime,
    },
    /// The PWM write failed; check the backend's device (the text names it).
    #[error("{0}")]
    Link(#[from] LinkError),
}
