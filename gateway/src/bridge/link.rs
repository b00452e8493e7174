//! The link between sites: one Zenoh session over mutual TLS, with access control that lets
//! each configured site's certificate (common name `rove-site-NAME`) put only under its own
//! name and subscribe only to what is addressed to it (rove_core::site). What arrives goes to
//! the bridge's loop through a bounded channel; a full channel drops (counted), so Zenoh's
//! threads never wait for the loop.

use crate::config::ZenohLink;
use rove_core::site::{ALL_LIVE, Key, Policy, SiteName, Subject};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use tokio::sync::mpsc;
use zenoh::qos::{CongestionControl, Priority};

/// What the link brought.
#[derive(Debug)]
pub(super) enum Arrived {
    /// A message under `key`: its payload, or `None` for a delete.
    Message { key: String, put: Option<Vec<u8>> },
    /// A site's bridge came (`up`) or went (its token withdrawn, or its link lost).
    Site { site: SiteName, up: bool },
}

/// The open link.
pub(super) struct Link {
    session: zenoh::Session,
    /// Messages the loop could not take in time (the channel was full).
    pub(super) dropped: Arc<AtomicU64>,
    _token: zenoh::liveliness::LivelinessToken,
    _inbox: zenoh::pubsub::Subscriber<()>,
    _sites: zenoh::pubsub::Subscriber<()>,
}

impl std::fmt::Debug for Link {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Link").finish_non_exhaustive()
    }
}

/// How many arrivals may wait for the loop.
const QUEUE: usize = 4096;

impl Link {
    /// Opens the session (a router if it listens, else a peer that connects, and keeps
    /// reconnecting), declares this site's liveliness token and subscribes to its inbox and to
    /// every bridge's token. Must run on a multi-thread runtime (Zenoh's own rule).
    ///
    /// The certificate files are the caller's to check first ([`ZenohLink::check_files`]).
    ///
    /// # Errors
    /// Zenoh refuses the configuration or cannot listen.
    pub(super) async fn open(
        policy: &Policy,
        link: &ZenohLink,
    ) -> anyhow::Result<(Link, mpsc::Receiver<Arrived>)> {
        let config = zenoh_config(policy, link)?;
        let session = zenoh::open(config)
            .await
            .map_err(|e| anyhow::anyhow!("cannot open the link to other sites: {e}"))?;
        let (tx, rx) = mpsc::channel(QUEUE);
        let dropped = Arc::new(AtomicU64::new(0));
        let send = {
            let (tx, dropped) = (tx.clone(), dropped.clone());
            move |arrived| {
                if tx.try_send(arrived).is_err() {
                    dropped.fetch_add(1, Ordering::Relaxed);
                }
            }
        };
        let inbox = {
            let send = send.clone();
            session
                .declare_subscriber(policy.me.inbox())
                .callback(move |sample: zenoh::sample::Sample| {
                    let put = match sample.kind() {
                        // Longer than any payload the bridge reads: refused uncopied.
                        zenoh::sample::SampleKind::Put
                            if sample.payload().len() > rove_core::site::wire::MAX_PAYLOAD =>
                        {
                            Some(Vec::new())
                        }
                        zenoh::sample::SampleKind::Put => {
                            Some(sample.payload().to_bytes().into_owned())
                        }
                        zenoh::sample::SampleKind::Delete => None,
                    };
                    let key = sample.key_expr().as_str().to_string();
                    send(Arrived::Message { key, put });
                })
                .await
                .map_err(|e| anyhow::anyhow!("cannot subscribe: {e}"))?
        };
        let sites = session
            .liveliness()
            .declare_subscriber(ALL_LIVE)
            .history(true)
            .callback(move |sample: zenoh::sample::Sample| {
                if let Some(site) = SiteName::of_liveliness(sample.key_expr().as_str()) {
                    let up = sample.kind() == zenoh::sample::SampleKind::Put;
                    send(Arrived::Site { site, up });
                }
            })
            .await
            .map_err(|e| anyhow::anyhow!("cannot watch other sites: {e}"))?;
        let token = session
            .liveliness()
            .declare_token(policy.me.liveliness())
            .await
            .map_err(|e| anyhow::anyhow!("cannot declare this site: {e}"))?;
        let link = Link {
            session,
            dropped,
            _token: token,
            _inbox: inbox,
            _sites: sites,
        };
        Ok((link, rx))
    }

    /// Sends `payload` under `key` (`None`: a delete). Nothing waits: a congested link drops
    /// (commands are streamed, DeviceInfo refreshed, requests resent).
    pub(super) async fn send(&self, key: &Key, payload: Option<Vec<u8>>) {
        let (priority, express) = match key.subject {
            Subject::Command { .. } => (Priority::InteractiveHigh, true),
            Subject::Request(_) => (Priority::InteractiveLow, true),
            Subject::Info(_) | Subject::Status(_) => (Priority::Data, false),
        };
        let key = key.render();
        let sent = match payload {
            Some(payload) => {
                self.session
                    .put(&key, payload)
                    .congestion_control(CongestionControl::Drop)
                    .priority(priority)
                    .express(express)
                    .await
            }
            None => {
                self.session
                    .delete(&key)
                    .congestion_control(CongestionControl::Drop)
                    .priority(priority)
                    .express(express)
                    .await
            }
        };
        if let Err(e) = sent {
            tracing::debug!(%key, cause = %e, "not sent");
        }
    }

    /// Closes the session: other sites see this site's token go at once.
    pub(super) async fn close(self) {
        if let Err(e) = self.session.close().await {
            tracing::warn!(cause = %e, "closing the link");
        }
    }
}

/// The Zenoh configuration: mode, endpoints, mutual TLS, lease, no scouting (nothing is sent
/// anywhere but the configured endpoints), and the access control.
fn zenoh_config(policy: &Policy, link: &ZenohLink) -> anyhow::Result<zenoh::Config> {
    let path = |p: &std::path::Path| json(p.to_string_lossy());
    let mode = if link.listen.is_empty() {
        "peer"
    } else {
        "router"
    };
    let settings: Vec<(&str, String)> = vec![
        ("mode", json(mode)),
        ("listen/endpoints", json(&link.listen)),
        ("connect/endpoints", json(&link.connect)),
        // Keep connecting in the background, at most 2 s apart, however long the other
        // site is away.
        ("connect/timeout_ms", "-1".into()),
        ("connect/exit_on_failure", "false".into()),
        (
            "connect/retry",
            r#"{"period_init_ms": 250, "period_max_ms": 2000, "period_increase_factor": 2}"#.into(),
        ),
        ("scouting/multicast/enabled", "false".into()),
        ("scouting/gossip/enabled", "false".into()),
        ("timestamping/enabled", "false".into()),
        (
            "transport/link/tx/lease",
            link.lease.as_millis().to_string(),
        ),
        ("transport/link/tx/keep_alive", "4".into()),
        // A message is a few hundred bytes; Zenoh's default would reassemble up to 1 GiB
        // from one (authenticated) peer.
        ("transport/link/rx/max_message_size", "8192".into()),
        // A congested link drops at once rather than holding the bridge's loop (and every
        // other site's traffic) up to 1 ms per message: commands are a stream, the rest is
        // refreshed or resent.
        (
            "transport/link/tx/queue/congestion_control/drop/wait_before_drop",
            "0".into(),
        ),
        ("transport/link/tls/root_ca_certificate", path(&link.ca)),
        (
            "transport/link/tls/listen_certificate",
            path(&link.certificate),
        ),
        ("transport/link/tls/listen_private_key", path(&link.key)),
        (
            "transport/link/tls/connect_certificate",
            path(&link.certificate),
        ),
        ("transport/link/tls/connect_private_key", path(&link.key)),
        ("transport/link/tls/enable_mtls", "true".into()),
        ("transport/link/tls/verify_name_on_connect", "true".into()),
        // A site whose certificate expires is cut off then, not at its next connection.
        ("transport/link/tls/close_link_on_expiration", "true".into()),
        ("access_control", access_control(policy).to_string()),
    ];
    let mut config = zenoh::Config::default();
    for (key, value) in settings {
        config
            .insert_json5(key, &value)
            .map_err(|e| anyhow::anyhow!("link setting {key} = {value}: {e}"))?;
    }
    Ok(config)
}

/// `value` as JSON5 (JSON is JSON5).
fn json(value: impl serde::Serialize) -> String {
    // Strings and lists of strings always serialise.
    serde_json::to_string(&value).unwrap_or_default()
}

/// Everything is refused but, for each configured site's certificate: putting and deleting
/// under its own name, subscribing to what is addressed to it, its own liveliness token,
/// watching the tokens; and sending it anything of rove's (what it may subscribe to decides
/// what it gets). A certificate of the fleet that names no configured site may connect but
/// can do nothing.
fn access_control(policy: &Policy) -> serde_json::Value {
    use serde_json::json;
    let all = [
        "put",
        "delete",
        "declare_subscriber",
        "query",
        "declare_queryable",
        "reply",
        "liveliness_token",
        "declare_liveliness_subscriber",
        "liveliness_query",
    ];
    let mut rules = vec![json!({
        "id": "to-sites", "messages": all, "flows": ["egress"], "permission": "allow",
        "key_exprs": ["rove/**", "rove-live/**"],
    })];
    let watch = json!({
        "id": "watch", "messages": ["declare_liveliness_subscriber", "liveliness_query"],
        "flows": ["ingress"], "permission": "allow", "key_exprs": [ALL_LIVE],
    });
    rules.push(watch);
    let (mut subjects, mut policies) = (Vec::new(), Vec::new());
    for peer in &policy.peers {
        let name = peer.name.as_str();
        let rule = |what: &str, messages: &[&str], key: String| {
            json!({
                "id": format!("{what}-{name}"), "messages": messages, "flows": ["ingress"],
                "permission": "allow", "key_exprs": [key],
            })
        };
        rules.push(rule("say", &["put", "delete"], format!("rove/*/{name}/**")));
        rules.push(rule("hear", &["declare_subscriber"], peer.name.inbox()));
        rules.push(rule("live", &["liveliness_token"], peer.name.liveliness()));
        subjects.push(
            json!({ "id": format!("site-{name}"), "cert_common_names": [peer.name.common_name()] }),
        );
        policies.push(json!({
            "rules": ["to-sites", "watch", format!("say-{name}"), format!("hear-{name}"), format!("live-{name}")],
            "subjects": [format!("site-{name}")],
        }));
    }
    json!({
        "enabled": true,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    })
}
