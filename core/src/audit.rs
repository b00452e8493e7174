//! The audit of control: who drove a vehicle, when and why, as a hash chain (issue 44).
//!
//! Each [`Entry`] is one JSON line. Its `hash` is SHA-256 over its body (every other field,
//! serialized in field order), and the body holds the previous entry's hash (`prev`) and a
//! sequence number (`seq`, +1 each). So an edited entry no longer matches its hash, a removed
//! or reordered one breaks the sequence and the link, and an entry cannot be replaced without
//! rewriting every later one. The writer also keeps a [`Checkpoint`] (the last entry made
//! durable) apart from the log: a log that ends before it was cut short.
//!
//! What this does not prove: a chain rewritten from some point on, checkpoint included, by
//! someone who can write the vehicle's disk. Copy the log off the vehicle, or sign the
//! checkpoint, for that (docs/security.md, "Audit").
//!
//! Pure: no clock, no files. The gateway's `audit` module writes, rotates and syncs.

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

/// The `prev` of the first entry a vehicle ever writes: 64 zeros.
pub const GENESIS: &str = "0000000000000000000000000000000000000000000000000000000000000000";

/// Why control changed (or the gateway started or stopped).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Why {
    /// The vehicle's gateway started: its failsafe holds the outputs.
    Start,
    /// A controller became live while the failsafe owned.
    Join,
    /// A stronger live controller took over.
    Preempt,
    /// The owner released, or its writer or participant left.
    Quit,
    /// The owner fell silent for the command timeout.
    Crash,
    /// The holder of an accepted request (priority grant) took over.
    Grant,
    /// The grant was given back (FINISH).
    Finish,
    /// The output adapter failed: the vehicle is held safe.
    OutputDown,
    /// The output adapter works again: the owner's commands reach the vehicle again.
    OutputBack,
    /// The vehicle's gateway stopped: outputs to their safe state.
    Stop,
}

/// Who holds control after the change.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Who {
    /// The device id it sends as; `None`: the vehicle's own failsafe.
    pub device: Option<i64>,
    /// Its DDS participant (GUID prefix, hex), who sent it on the wire.
    pub participant: Option<String>,
    /// How the id is known: the fleet certificate that names it (`"certificate of device 11"`,
    /// or `"site proxy certificate of device 21 (up to Remote)"` for another site's device) or,
    /// unsecured, `"unsecured id 11"`; `"failsafe"`.
    pub identity: String,
    /// Its ownership strength (0: the failsafe).
    pub strength: u16,
}

/// What happened, as the vehicle's gateway reports it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Event {
    /// Wall clock, µs since the Unix epoch.
    pub wall_us: u64,
    /// The vehicle.
    pub vehicle: i64,
    /// Who drives from now on.
    pub who: Who,
    /// Why.
    pub why: Why,
}

impl Why {
    /// The audit's word for an arbiter's reason.
    pub fn of(reason: crate::arbiter::Reason) -> Why {
        use crate::arbiter::Reason;
        match reason {
            Reason::Joined => Why::Join,
            Reason::Preempted => Why::Preempt,
            Reason::Released | Reason::Left => Why::Quit,
            Reason::TimedOut => Why::Crash,
            Reason::Granted => Why::Grant,
            Reason::GrantReturned => Why::Finish,
        }
    }
}

impl Who {
    /// Who `owner` is. Its device id is the one the arbiter believed: under DDS Security
    /// (`certifier`) only from a participant whose certificate names it, so the certificate is
    /// the identity (the device's own, or a site proxy's: another site's device shown by this
    /// site's bridge); else only the id.
    pub fn of(owner: &crate::arbiter::Owner, certifier: Option<&crate::trust::Certifier>) -> Who {
        use crate::trust::Certified;
        match owner {
            crate::arbiter::Owner::Failsafe => Who {
                device: None,
                participant: None,
                identity: "failsafe".into(),
                strength: 0,
            },
            crate::arbiter::Owner::Controller(c) => Who {
                device: Some(c.device),
                participant: Some(c.writer.participant.to_string()),
                identity: match certifier.map(|f| f(c.device, c.writer.participant)) {
                    None => format!("unsecured id {}", c.device),
                    Some(Certified::Device) => format!("certificate of device {}", c.device),
                    Some(Certified::Proxy(level)) => format!(
                        "site proxy certificate of device {} (up to {level:?})",
                        c.device
                    ),
                    // The arbiter believed none such; said, should it happen.
                    Some(Certified::No) => format!("uncertified id {}", c.device),
                },
                strength: c.strength.0,
            },
        }
    }
}

/// One line of the log.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Entry {
    /// Position in the vehicle's chain, from 0.
    pub seq: u64,
    /// What happened.
    #[serde(flatten)]
    pub event: Event,
    /// The previous entry's hash ([`GENESIS`] for the first).
    pub prev: String,
    /// SHA-256 of this entry's body, hex.
    pub hash: String,
}

/// The hashed part of an entry: everything but the hash, in a fixed order.
#[derive(Serialize)]
struct Body<'a> {
    seq: u64,
    #[serde(flatten)]
    event: &'a Event,
    prev: &'a str,
}

/// The hash of an entry made of these parts.
fn hash_of(seq: u64, event: &Event, prev: &str) -> String {
    let body = serde_json::to_vec(&Body { seq, event, prev }).unwrap_or_default();
    let digest = Sha256::digest(&body);
    digest.iter().map(|b| format!("{b:02x}")).collect()
}

/// The last entry made durable: kept apart from the log, so that a log cut short shows.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Checkpoint {
    /// Its sequence number.
    pub seq: u64,
    /// Its hash.
    pub hash: String,
}

/// The end of a chain: where the next entry links.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Chain {
    next_seq: u64,
    last: String,
}

impl Default for Chain {
    fn default() -> Self {
        Chain {
            next_seq: 0,
            last: GENESIS.to_string(),
        }
    }
}

impl Chain {
    /// A chain that goes on after `last` (the log's last entry), or a new one.
    pub fn after(last: Option<&Entry>) -> Chain {
        last.map_or_else(Chain::default, |e| Chain {
            next_seq: e.seq + 1,
            last: e.hash.clone(),
        })
    }

    /// The next entry for `event`, linked to the chain.
    pub fn append(&mut self, event: Event) -> Entry {
        let seq = self.next_seq;
        let hash = hash_of(seq, &event, &self.last);
        let entry = Entry {
            seq,
            event,
            prev: std::mem::replace(&mut self.last, hash.clone()),
            hash,
        };
        self.next_seq += 1;
        entry
    }

    /// Where the chain stands, for the checkpoint.
    pub fn checkpoint(&self) -> Option<Checkpoint> {
        (self.next_seq > 0).then(|| Checkpoint {
            seq: self.next_seq - 1,
            hash: self.last.clone(),
        })
    }
}

/// What [`verify`] found wrong, with the line (`line`: 1-based, over the files in order;
/// `seq`: the entry's sequence number).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[allow(missing_docs)] // the fields are named above
pub enum Broken {
    /// A line that is not an entry.
    #[error("line {line}: not an audit entry: {why}")]
    Unreadable { line: usize, why: String },
    /// An entry whose hash does not match its contents: edited.
    #[error("line {line}: entry {seq} was changed after it was written (its hash does not match)")]
    Edited { line: usize, seq: u64 },
    /// An entry that does not follow the one before it: removed, inserted or reordered.
    #[error(
        "line {line}: entry {seq} does not follow entry {after} (entries removed, inserted or \
         reordered)"
    )]
    OutOfChain { line: usize, seq: u64, after: u64 },
    /// The first entry of a chain that claims to be the first of all but does not start it.
    #[error("line {line}: entry 0 does not start a chain")]
    BadStart { line: usize },
    /// The log ends before the checkpoint: cut short.
    #[error(
        "the log ends at entry {last:?}, before the checkpoint (entry {checkpoint}): truncated"
    )]
    Truncated { last: Option<u64>, checkpoint: u64 },
    /// The checkpoint's entry is in the log with another hash.
    #[error("entry {seq} differs from the checkpoint's")]
    CheckpointMismatch { seq: u64 },
}

/// A chain that verified.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Verified {
    /// Entries read.
    pub entries: usize,
    /// The first entry's sequence number (above 0: older entries were rotated away).
    pub first: Option<u64>,
    /// Entries after the checkpoint (written less than a second before the last sync).
    pub after_checkpoint: u64,
}

/// Checks `lines` (the log's files, oldest first, concatenated) against each other and against
/// `checkpoint`. Blank lines are skipped.
///
/// # Errors
/// The first break found.
pub fn verify<'a>(
    lines: impl IntoIterator<Item = &'a str>,
    checkpoint: Option<&Checkpoint>,
) -> Result<Verified, Broken> {
    let mut previous: Option<Entry> = None;
    let (mut entries, mut first) = (0, None);
    for (n, text) in lines.into_iter().enumerate() {
        let line = n + 1;
        if text.trim().is_empty() {
            continue;
        }
        let e: Entry = serde_json::from_str(text).map_err(|e| Broken::Unreadable {
            line,
            why: e.to_string(),
        })?;
        if hash_of(e.seq, &e.event, &e.prev) != e.hash {
            return Err(Broken::Edited { line, seq: e.seq });
        }
        match &previous {
            Some(p) if e.seq != p.seq + 1 || e.prev != p.hash => {
                return Err(Broken::OutOfChain {
                    line,
                    seq: e.seq,
                    after: p.seq,
                });
            }
            None if e.seq == 0 && e.prev != GENESIS => return Err(Broken::BadStart { line }),
            _ => {}
        }
        first = first.or(Some(e.seq));
        entries += 1;
        previous = Some(e);
    }
    let last = previous.as_ref().map(|e| e.seq);
    let after_checkpoint = match checkpoint {
        None => 0,
        Some(c) if last.is_none_or(|l| l < c.seq) => {
            return Err(Broken::Truncated {
                last,
                checkpoint: c.seq,
            });
        }
        Some(c) => {
            if last == Some(c.seq) && previous.as_ref().is_some_and(|p| p.hash != c.hash) {
                return Err(Broken::CheckpointMismatch { seq: c.seq });
            }
            last.unwrap_or(0) - c.seq
        }
    };
    Ok(Verified {
        entries,
        first,
        after_checkpoint,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn event(k: u64, why: Why) -> Event {
        Event {
            wall_us: 1_700_000_000_000_000 + k,
            vehicle: 100,
            who: Who {
                device: Some(11),
                participant: Some("0102".into()),
                identity: "unsecured id 11".into(),
                strength: 330,
            },
            why,
        }
    }

    /// A chain of `n` entries as JSON lines, and its checkpoint.
    fn log(n: u64) -> (Vec<String>, Option<Checkpoint>) {
        let mut chain = Chain::default();
        let lines = (0..n)
            .map(|k| serde_json::to_string(&chain.append(event(k, Why::Join))).expect("test step"))
            .collect();
        (lines, chain.checkpoint())
    }

    fn check(lines: &[String], c: Option<&Checkpoint>) -> Result<Verified, Broken> {
        verify(lines.iter().map(String::as_str), c)
    }

    #[test]
    fn a_chain_verifies_and_goes_on_after_its_last_entry() {
        let (mut lines, c) = log(5);
        let v = check(&lines, c.as_ref()).expect("test step");
        assert_eq!((v.entries, v.first, v.after_checkpoint), (5, Some(0), 0));
        let last: Entry = serde_json::from_str(&lines[4]).expect("test step");
        let mut chain = Chain::after(Some(&last));
        lines.push(serde_json::to_string(&chain.append(event(9, Why::Stop))).expect("test step"));
        // One entry after the checkpoint: written after the last sync, still a chain.
        assert_eq!(
            check(&lines, c.as_ref())
                .expect("test step")
                .after_checkpoint,
            1
        );
    }

    #[test]
    fn an_edited_entry_is_found() {
        let (mut lines, c) = log(4);
        lines[2] = lines[2].replace("\"device\":11", "\"device\":12");
        assert_eq!(
            check(&lines, c.as_ref()),
            Err(Broken::Edited { line: 3, seq: 2 })
        );
    }

    #[test]
    fn reordered_and_removed_entries_are_found() {
        let (mut lines, c) = log(4);
        lines.swap(1, 2);
        assert!(matches!(
            check(&lines, c.as_ref()),
            Err(Broken::OutOfChain { line: 2, .. })
        ));
        let (mut lines, c) = log(4);
        lines.remove(1);
        assert!(matches!(
            check(&lines, c.as_ref()),
            Err(Broken::OutOfChain {
                line: 2,
                seq: 2,
                ..
            })
        ));
    }

    #[test]
    fn a_truncated_log_is_found_by_its_checkpoint() {
        let (mut lines, c) = log(4);
        lines.pop();
        assert_eq!(
            check(&lines, c.as_ref()),
            Err(Broken::Truncated {
                last: Some(2),
                checkpoint: 3
            })
        );
        assert!(matches!(
            check(&[], c.as_ref()),
            Err(Broken::Truncated { last: None, .. })
        ));
    }

    #[test]
    fn a_rotated_chain_starts_anywhere_but_entry_zero_starts_at_genesis() {
        let (lines, c) = log(6);
        // The oldest file was rotated away: the rest still verifies.
        assert_eq!(
            check(&lines[3..], c.as_ref()).expect("test step").first,
            Some(3)
        );
        // A forged entry 0 must start at genesis.
        let mut forged: Entry = serde_json::from_str(&lines[0]).expect("test step");
        forged.prev = "ab".repeat(32);
        forged.hash = hash_of(forged.seq, &forged.event, &forged.prev);
        let forged = [serde_json::to_string(&forged).expect("test step")];
        assert_eq!(check(&forged, None), Err(Broken::BadStart { line: 1 }));
    }

    #[test]
    fn garbage_is_unreadable_not_a_panic() {
        for text in ["{", "[]", "{\"seq\":-1}", "\u{0}"] {
            let lines = [text.to_string()];
            assert!(matches!(
                check(&lines, None),
                Err(Broken::Unreadable { line: 1, .. })
            ));
        }
    }

    proptest! {
        /// Any change to any byte of any line of a chain is found (or the line becomes
        /// unreadable): nothing verifies but the chain as written.
        #[test]
        fn any_single_byte_change_is_found(n in 1u64..8, pick in any::<prop::sample::Index>(),
                                           at in any::<prop::sample::Index>(), to in any::<u8>()) {
            let (lines, c) = log(n);
            let k = pick.index(lines.len());
            let mut bytes = lines[k].clone().into_bytes();
            let i = at.index(bytes.len());
            prop_assume!(bytes[i] != to);
            bytes[i] = to;
            let mut changed = lines.clone();
            changed[k] = String::from_utf8_lossy(&bytes).into_owned();
            prop_assume!(changed[k] != lines[k]);
            // A change that still parses to the same entry (JSON whitespace) is no change.
            let same = serde_json::from_str::<Entry>(&changed[k]).ok()
                == serde_json::from_str::<Entry>(&lines[k]).ok();
            prop_assume!(!same);
            prop_assert!(check(&changed, c.as_ref()).is_err());
        }
    }
}
