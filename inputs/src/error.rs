//! The crate's error type: problems with recordings and device files, each naming the file and,
//! for recordings, the line.

use std::path::PathBuf;

/// Result alias for fallible `rove-inputs` functions.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Errors of `rove-inputs` functions other than configuration validation (which returns
/// [`rove_core::Error::Config`]) and input polling (which returns [`rove_core::error::LinkError`]).
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A recording could not be read; check that the path in `[input] file` exists and is
    /// readable.
    #[error("cannot read recording {path}: {source}")]
    ReadRecording {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// A text recording has a line that does not parse; the message says what was expected
    /// (see the crate README for the format).
    #[error("{path}:{line}: {detail}")]
    RecordingSyntax {
        /// The file (or `<memory>` for recordings parsed from a string).
        path: PathBuf,
        /// 1-based line number.
        line: usize,
        /// What is wrong, quoting the offending token.
        detail: String,
    },
    /// A binary recording's length is not a whole number of 24-byte `struct input_event`
    /// records: the file is truncated or is not a raw evdev capture.
    #[error("{path}: {len} bytes is not a whole number of 24-byte input_event records")]
    RecordingLength {
        /// The file.
        path: PathBuf,
        /// Its length in bytes.
        len: usize,
    },
}
