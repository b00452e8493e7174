//! Zenoh's TLS failures on the site link, told in rove's words (issue 49).
//!
//! Zenoh reports a refused handshake on the listening side as a warning with a hint about the
//! open file limit (its accept loop's advice for every accept error), and on the connecting side
//! only at DEBUG. The bridge's log shows neither of those; a [`Watch`] layer sees them whatever
//! the log's level and says, once per kind and [`INTERVAL`], which side refused which
//! certificate, the CA this site trusts, and what to check ([`explain`], pure). Other warnings
//! of Zenoh's TLS link are passed on as they are, without the hint.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Mutex;
use std::time::{Duration, Instant};
use tracing::field::{Field, Visit};
use tracing::{Event, Level, Subscriber, warn};
use tracing_subscriber::filter::Targets;
use tracing_subscriber::layer::{Context, Layer};

/// Zenoh's TLS link: its warnings (the listening side's refused handshakes among them).
const TLS_TARGET: &str = "zenoh_link_tls";
/// Zenoh's connector: a configured peer it could not reach, at DEBUG.
const CONNECT_TARGET: &str = "zenoh::net::runtime::orchestrator";
/// How Zenoh's connector says it.
const CONNECT_FAILED: &str = "Unable to connect to configured peer ";
/// Zenoh's misleading advice on every refused handshake.
const HINT: &str = ". Hint: increase the system open file limit.";
/// One line per kind of refusal this often: a bridge retries every few seconds.
pub const INTERVAL: Duration = Duration::from_secs(30);

/// Why a TLS handshake failed, as far as its error text tells.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Refusal {
    /// The other bridge does not know the CA that signed this site's certificate.
    TheyDoNotKnowOurCa,
    /// The other bridge's certificate is not signed by the CA this site trusts.
    NotOurCa,
    /// The listening bridge's certificate does not name the address connected to.
    WrongAddress,
    /// A certificate has expired (or is not valid yet).
    Expired,
    /// The other bridge presented no certificate.
    NoCertificate,
    /// The other bridge refused this site's certificate (no more said).
    TheyRefusedOurs,
}

impl Refusal {
    /// What to check, for people.
    pub fn advice(self) -> &'static str {
        match self {
            Refusal::TheyDoNotKnowOurCa => {
                "the other bridge does not trust the CA that signed this site's certificate: \
                 both sites' certificates must come from the same fleet (`rove keys site` on \
                 the machine that holds its keys), each with that fleet's ca.cert.pem"
            }
            Refusal::NotOurCa => {
                "the other bridge's certificate is not signed by the CA this site trusts: make \
                 it with `rove keys site` from the same fleet as this site's, and give it that \
                 fleet's ca.cert.pem"
            }
            Refusal::WrongAddress => {
                "the listening bridge's certificate does not name the address connected to: \
                 make it with `rove keys site --host ADDRESS` for the address in `connect`"
            }
            Refusal::Expired => {
                "a certificate has expired or is not valid yet: check both sites' with \
                 `openssl x509 -noout -dates -in cert.pem` (and the clocks)"
            }
            Refusal::NoCertificate => {
                "the other side presented no certificate: a site link needs mutual TLS, each \
                 bridge with its `rove keys site` certificate"
            }
            Refusal::TheyRefusedOurs => {
                "the other bridge refused this site's certificate: check that both come from \
                 the same fleet and have not expired"
            }
        }
    }
}

/// What a TLS error text says went wrong (pure). rustls's words: an alert *received* is the
/// other side's verdict on our certificate; `invalid peer certificate` is ours on theirs.
pub fn explain(error: &str) -> Option<Refusal> {
    let has = |s: &str| error.contains(s);
    if has("NotValidForName") {
        return Some(Refusal::WrongAddress);
    }
    if has("Expired") || has("NotValidYet") {
        return Some(Refusal::Expired);
    }
    if has("received fatal alert") {
        return Some(if has("UnknownCA") {
            Refusal::TheyDoNotKnowOurCa
        } else if has("CertificateRequired") {
            Refusal::NoCertificate
        } else {
            Refusal::TheyRefusedOurs
        });
    }
    // UnknownIssuer, BadSignature, and whatever else makes their certificate not ours.
    if has("invalid peer certificate") {
        return Some(Refusal::NotOurCa);
    }
    if has("peer sent no certificates") || has("NoCertificatesPresented") {
        return Some(Refusal::NoCertificate);
    }
    None
}

/// An event's `message`, as text.
#[derive(Default)]
struct Message(String);

impl Visit for Message {
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            self.0 = format!("{value:?}");
        }
    }
}

/// Zenoh's lines queued for the teller; more are dropped (Zenoh retries every few seconds).
const QUEUE: usize = 64;

/// The layer: sees Zenoh's TLS warnings and failed connects (see [`Watch::filters`]) and hands
/// them to a thread of its own, which says them: an event logged from inside another event's
/// dispatch would upset the per-layer filters (the outer event then reached the log).
#[derive(Debug)]
pub struct Watch {
    queue: std::sync::mpsc::SyncSender<(String, String)>,
}

/// What says the refusals: the bridge's CA and listeners, and when each kind was last said.
#[derive(Debug)]
struct Teller {
    ca: PathBuf,
    listen: Vec<String>,
    last: Mutex<HashMap<(bool, Refusal), (Instant, u64)>>,
}

impl Watch {
    /// A watch for a bridge that trusts `ca` and listens on `listen`. Without its thread (it
    /// cannot be spawned) Zenoh's lines are dropped.
    pub fn new(ca: PathBuf, listen: Vec<String>) -> Watch {
        let (queue, lines) = std::sync::mpsc::sync_channel::<(String, String)>(QUEUE);
        let teller = Teller::new(ca, listen);
        let _ = std::thread::Builder::new()
            .name("rove-tls-watch".into())
            .spawn(move || {
                for (target, text) in lines {
                    teller.on_message(&target, &text);
                }
            });
        Watch { queue }
    }

    /// What it sees, and what the log no longer shows itself (this layer says it instead).
    pub fn filters() -> (Targets, Targets) {
        let sees = Targets::new()
            .with_target(TLS_TARGET, Level::WARN)
            .with_target(CONNECT_TARGET, Level::DEBUG);
        let hides = Targets::new().with_target(TLS_TARGET, Level::WARN);
        (sees, hides)
    }
}

impl Teller {
    fn new(ca: PathBuf, listen: Vec<String>) -> Teller {
        Teller {
            ca,
            listen,
            last: Mutex::new(HashMap::new()),
        }
    }

    /// Whether a line for this refusal is due; counts it otherwise.
    fn due(&self, listening: bool, refusal: Refusal) -> Option<u64> {
        let mut last = crate::runtime::lock(&self.last);
        let entry = last
            .entry((listening, refusal))
            .or_insert((Instant::now(), 0));
        if entry.1 == 0 || entry.0.elapsed() >= INTERVAL {
            let held_back = entry.1.saturating_sub(1);
            *entry = (Instant::now(), 1);
            Some(held_back)
        } else {
            entry.1 += 1;
            None
        }
    }

    fn on_message(&self, target: &str, text: &str) {
        if target.starts_with(TLS_TARGET) {
            let error = text.strip_suffix(HINT).unwrap_or(text);
            let Some(refusal) = explain(error) else {
                warn!(target: "rove_gateway::bridge::tls", "zenoh TLS: {error}");
                return;
            };
            if let Some(held_back) = self.due(true, refusal) {
                warn!(
                    listening = ?self.listen,
                    ca = %self.ca.display(),
                    error,
                    held_back,
                    "site link refused in the TLS handshake with a bridge connecting here: {}",
                    refusal.advice()
                );
            }
        } else if let Some(rest) = text.strip_prefix(CONNECT_FAILED) {
            let (endpoint, error) = rest.split_once("! ").unwrap_or((rest, rest));
            // Zenoh's errors end with where in Zenoh they were made, and the retry's delay.
            let error = error.split(" at /").next().unwrap_or(error);
            let Some(refusal) = explain(error) else {
                return; // not a certificate: down or unreachable, which `not connected` says
            };
            if let Some(held_back) = self.due(false, refusal) {
                warn!(
                    endpoint,
                    ca = %self.ca.display(),
                    error,
                    held_back,
                    "site link refused in the TLS handshake with the bridge at {endpoint}: {}",
                    refusal.advice()
                );
            }
        }
    }
}

impl<S: Subscriber> Layer<S> for Watch {
    fn on_event(&self, event: &Event<'_>, _: Context<'_, S>) {
        let mut message = Message::default();
        event.record(&mut message);
        let _ = (self.queue).try_send((event.metadata().target().to_string(), message.0));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The error texts seen from Zenoh 1.10 with rustls, on both sides of a refused link.
    #[test]
    fn tls_errors_are_explained() {
        for (text, want) in [
            (
                "received fatal alert: UnknownCA",
                Some(Refusal::TheyDoNotKnowOurCa),
            ),
            (
                "invalid peer certificate: BadSignature",
                Some(Refusal::NotOurCa),
            ),
            (
                "Can not create a new TLS link bound to tls/10.78.0.1:7447: invalid peer \
                 certificate: UnknownIssuer",
                Some(Refusal::NotOurCa),
            ),
            (
                "invalid peer certificate: NotValidForName",
                Some(Refusal::WrongAddress),
            ),
            ("invalid peer certificate: Expired", Some(Refusal::Expired)),
            (
                "received fatal alert: CertificateExpired",
                Some(Refusal::Expired),
            ),
            (
                "received fatal alert: BadCertificate",
                Some(Refusal::TheyRefusedOurs),
            ),
            ("peer sent no certificates", Some(Refusal::NoCertificate)),
            ("Connection refused (os error 111)", None),
            ("deadline has elapsed", None),
        ] {
            assert_eq!(explain(text), want, "{text}");
        }
    }

    #[test]
    fn one_line_per_kind_and_interval() {
        let watch = Teller::new("ca.cert.pem".into(), vec![]);
        assert_eq!(watch.due(true, Refusal::NotOurCa), Some(0));
        assert_eq!(watch.due(true, Refusal::NotOurCa), None);
        assert_eq!(watch.due(true, Refusal::NotOurCa), None);
        assert_eq!(
            watch.due(false, Refusal::NotOurCa),
            Some(0),
            "the other side's"
        );
        assert_eq!(watch.due(true, Refusal::Expired), Some(0), "another kind");
    }
}
