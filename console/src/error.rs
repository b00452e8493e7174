//! The crate's error type: why an API line was rejected, or why the socket could not be set up.

use std::path::PathBuf;

/// Errors of the local API.
///
/// Line errors ([`ApiError::TooLong`] … [`ApiError::UnknownField`]) are answered to the client
/// as `{"error": …, "code": …, "line": N}` and the connection stays open; socket errors end
/// [`crate::server::ApiSocket::bind`].
#[derive(Debug, thiserror::Error)]
pub enum ApiError {
    /// A line exceeded [`crate::api::MAX_LINE_BYTES`]; the client should send one command per
    /// line. The rest of the line is skipped.
    #[error("line too long: over {max} bytes")]
    TooLong {
        /// The limit.
        max: usize,
    },
    /// The line is not UTF-8.
    #[error("line is not UTF-8")]
    NotUtf8,
    /// The line is not JSON; the text is serde_json's (with the column).
    #[error("bad JSON: {0}")]
    BadJson(String),
    /// The JSON is not an object.
    #[error("a command must be a JSON object like {{\"cmd\":\"drive\",\"vehicle\":100}}")]
    NotAnObject,
    /// The object has no string `cmd` field.
    #[error("missing \"cmd\" (a string)")]
    MissingCmd,
    /// `cmd` names no command.
    #[error(
        "unknown command {0:?}: expected select, drive, release, request, accept, refuse, finish or mode"
    )]
    UnknownCmd(String),
    /// A required field is missing.
    #[error("{cmd}: missing field \"{field}\"")]
    MissingField {
        /// The command.
        cmd: &'static str,
        /// The field.
        field: &'static str,
    },
    /// A field has the wrong type or value.
    #[error("{cmd}: field \"{field}\": {why}")]
    InvalidField {
        /// The command.
        cmd: &'static str,
        /// The field.
        field: &'static str,
        /// What is wrong, e.g. "expected a device id (integer)".
        why: String,
    },
    /// A field the command does not have (a typo would otherwise be ignored silently).
    #[error("{cmd}: unknown field {field:?}")]
    UnknownField {
        /// The command.
        cmd: &'static str,
        /// The field.
        field: String,
    },
    /// The socket path exists and is not a socket: refusing to remove it. Check the
    /// `[console] api_socket` path in the config.
    #[error("{}: exists and is not a socket; not removing it", path.display())]
    NotASocket {
        /// The path.
        path: PathBuf,
    },
    /// Another process accepts connections on the socket path (another operator running with
    /// the same config?).
    #[error("{}: another process is listening on this socket", path.display())]
    InUse {
        /// The path.
        path: PathBuf,
    },
    /// Binding, removing the stale file or setting permissions failed (missing directory,
    /// no write permission).
    #[error("{}: {source}", path.display())]
    Socket {
        /// The path.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
}

impl ApiError {
    /// A stable machine-readable code for the reply's `code` field.
    pub fn code(&self) -> &'static str {
        match self {
            ApiError::TooLong { .. } => "too_long",
            ApiError::NotUtf8 => "not_utf8",
            ApiError::BadJson(_) => "bad_json",
            ApiError::NotAnObject => "not_object",
            ApiError::MissingCmd => "missing_cmd",
            ApiError::UnknownCmd(_) => "unknown_cmd",
            ApiError::MissingField { .. } => "missing_field",
            ApiError::InvalidField { .. } => "invalid_field",
            ApiError::UnknownField { .. } => "unknown_field",
            ApiError::NotASocket { .. } | ApiError::InUse { .. } | ApiError::Socket { .. } => {
                "socket"
            }
        }
    }
}

/// `Result` with [`ApiError`].
pub type Result<T> = std::result::Result<T, ApiError>;
