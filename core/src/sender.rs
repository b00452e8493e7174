//! Who sent a message: the process (a DDS participant) and the stream in it (a writer), as
//! opaque numbers the binding derives from DDS identities. Never a payload field. The arbiter,
//! the trust rules and the session all name senders so; nothing here depends on them.

use std::fmt;

/// A process on the network that owns writers (a DDS participant), as an opaque number the
/// binding derives from its identity (the GUID prefix).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct ParticipantId(pub u128);

/// One command stream's identity: which process, and which writer in it (a DDS writer GUID).
/// Ordered, so that ties are broken deterministically.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct WriterId {
    /// The process the writer belongs to.
    pub participant: ParticipantId,
    /// The writer within that process.
    pub entity: u32,
}

/// The participant's 12-byte GUID prefix in hex.
impl fmt::Display for ParticipantId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:024x}", self.0)
    }
}

impl fmt::Display for WriterId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:x}/{:x}", self.participant.0, self.entity)
    }
}
