//! The crate's own error type: a CAN frame that cannot be built. Configuration problems are
//! [`rove_core::error::ConfigErrors`] and bus failures are [`rove_core::error::LinkError`]s.

/// Result alias for `rove-can`.
pub type Result<T, E = FrameError> = std::result::Result<T, E>;

/// Why a CAN frame could not be built or a field not written into it. Validation rules out
/// every one of these for frames built from a validated [`crate::CanConfig`]; they exist so that
/// the encoders never panic on a value they were not meant to see.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// The identifier does not fit its format (11 bits standard, 29 bits extended); check the
    /// frame's `id` and `extended` keys.
    #[error("CAN id 0x{id:X} does not fit a {} identifier", if *.extended { "29-bit extended" } else { "11-bit standard" })]
    IdOutOfRange {
        /// The identifier.
        id: u32,
        /// Whether an extended identifier was asked for.
        extended: bool,
    },
    /// More data than a frame holds: 8 bytes classic, 64 bytes CAN FD.
    #[error("{len} data bytes do not fit a CAN frame (8 classic, 64 CAN FD)")]
    DataTooLong {
        /// The data length asked for.
        len: usize,
    },
    /// A CAN FD frame longer than 8 bytes must be 12, 16, 20, 24, 32, 48 or 64 bytes long.
    #[error("{len} bytes is not a CAN FD data length (12, 16, 20, 24, 32, 48 or 64)")]
    InvalidFdLength {
        /// The data length asked for.
        len: usize,
    },
    /// A field reaches past the end of its frame.
    #[error("a {bytes}-byte field at offset {offset} does not fit a {frame_len}-byte frame")]
    FieldOutOfFrame {
        /// First byte of the field.
        offset: usize,
        /// Width of the field in bytes.
        bytes: usize,
        /// Length of the frame.
        frame_len: usize,
    },
}
