//! `rove bridge`: a site's link to other sites (docs/remote.md, docs/design.md "Remote sites").
//!
//! One bridge per site joins the site's DDS network and a Zenoh link to the bridges of the
//! sites it is configured to meet. It carries its devices' DeviceInfo, VehicleStatus,
//! ControlCommand streams (with their strength and releases) and RequestControl to the sites
//! concerned, and gives every device of another site a participant of its own here
//! (a proxy), so vehicles, operators, the trust rules and the handover see it as any
//! device: a remote operator drives with its own strength, quits with a release, and one that
//! crashes or whose link dies leaves as a local one does. Identity is never a payload's: a
//! local device is who its DeviceInfo's participant is, and another site speaks only under
//! its certificate's name (the link's access control) and for the ids configured for it
//! ([`rove_core::site::Policy`]).

mod inbound;
mod link;
mod local;
mod proxy;
mod revoked;
mod secured;
mod sites;
mod tls;

use crate::config::{BridgeConfig, Common};
use crate::runtime::{Clock, RateLimited};
use crate::sdnotify::Notifier;
use link::{Arrived, Link};
use local::{Heard, Local};
use proxy::{Proxy, Read};
use revoked::Revocations;
use rove_core::arbiter::ParticipantId;
use rove_core::hierarchy::Strength;
use rove_core::msg::{DeviceId, DeviceInfo, RequestControl, VehicleStatus};
use rove_core::site::absence::Absences;
use rove_core::site::{Key, Policy, SiteName, Subject, wire};
use rustdds::GUID;
use rustdds::with_key::Sample;
use secured::{Secured, identities};
use std::collections::{BTreeSet, HashMap};
use std::time::{Duration, Instant};
use tokio::sync::mpsc;
use tracing::{info, warn};

/// The bridge's watch of Zenoh's TLS failures (`bridge/tls.rs`): for
/// [`crate::runtime::init_logging_with`].
pub fn tls_watch(config: &BridgeConfig) -> crate::runtime::Watch {
    let (sees, hides) = tls::Watch::filters();
    crate::runtime::Watch {
        layer: Box::new(tls::Watch::new(
            config.link.ca.clone(),
            config.link.listen.clone(),
        )),
        sees,
        hides,
    }
}

/// How often proxies' DeviceInfo refreshes are checked and stale proxies dropped.
const TICK: Duration = Duration::from_millis(500);

/// Most devices of other sites proxied here, and most local devices followed.
const MAX_DEVICES: usize = 1024;

/// What `rove bridge` checks before it starts: this site is not revoked, and on a secured site
/// its DDS identities are complete ([`run`] checks them again).
///
/// # Errors
/// This site is revoked, the revoked sites' list is not the fleet CA's, or a secured site's
/// directory is incomplete: a config error, which a restart cannot fix.
pub fn check(config: &BridgeConfig) -> anyhow::Result<()> {
    identities(config).map(|_| ())
}

/// Runs the bridge until `shutdown`. Needs a multi-thread runtime (Zenoh's rule).
///
/// Under systemd (see [`crate::sdnotify`]): `READY=1` once the DDS participant and the link
/// are open, a `STATUS=` line whenever the sites up or the device counts change, keep-alives
/// from the loop, `STOPPING=1` before the proxies leave.
///
/// The link's certificate files are checked before ([`ZenohLink::check_files`]), and so is
/// [`check`]: `rove bridge` does so ahead of the runtime, so that a missing file, a revoked site
/// or a missing proxy certificate is a config error (exit 78).
///
/// # Errors
/// The DDS participant or the link cannot be opened, or a DDS stream ended.
///
/// [`ZenohLink::check_files`]: crate::config::ZenohLink::check_files
pub async fn run(
    config: BridgeConfig,
    mut notify: Notifier,
    shutdown: impl std::future::Future<Output = ()>,
) -> anyhow::Result<()> {
    let (revoked, policy, secured) = identities(&config)?;
    let mut local = Local::join(&config.common, secured.as_ref().map(Secured::own))?;
    let (link, mut arrived) = Link::open(&policy, &config.link).await?;
    let (read_tx, mut read) = mpsc::channel(4096);
    let policy = &policy;
    let peers: Vec<String> = (policy.peers.iter())
        .map(|p| {
            format!(
                "{} (ids {:?}, offered {:?}, up to {:?})",
                p.name, p.ids, p.offer, p.level
            )
        })
        .collect();
    info!(
        site = %policy.me,
        listen = ?config.link.listen,
        connect = ?config.link.connect,
        ?peers,
        domain = config.common.domain_id,
        interfaces = ?config.common.interfaces,
        watchdog_keepalive_ms = notify.watchdog_period().map(|p| p.as_millis() as u64),
        "bridge started"
    );
    let identities = (revoked, secured);
    let mut bridge = Bridge::new(
        config.common.clone(),
        policy.clone(),
        link,
        read_tx,
        identities,
    );
    let mut tick = tokio::time::interval(TICK);
    let mut keepalive = notify.keepalive_timer();
    let mut shown = bridge.counts();
    notify.ready(&bridge.status_line());
    tokio::pin!(shutdown);
    let result = loop {
        tokio::select! {
            () = &mut shutdown => break Ok(()),
            heard = local.heard() => match heard {
                Ok(heard) => bridge.local(heard).await,
                Err(e) => break Err(e),
            },
            Some(arrived) = arrived.recv() => bridge.arrived(arrived).await,
            Some(one) = read.recv() => bridge.read(one).await,
            _ = tick.tick() => bridge.tick().await,
            () = keepalive.tick() => notify.keepalive(),
        }
        // Counted each turn, the line written only when a count changed.
        let counts = bridge.counts();
        if counts != shown {
            shown = counts;
            notify.status(&bridge.status_line());
        }
    };
    notify.stopping("stopping: other sites' devices leave this site, the link closes");
    bridge.leave().await;
    result
}

/// A local device: its participant and what it last said.
#[derive(Debug)]
struct LocalDevice {
    participant: ParticipantId,
    info: DeviceInfo,
    status: Option<VehicleStatus>,
    /// When its participant last said something (a DeviceInfo refresh at least every
    /// [`crate::dds::DEVICE_INFO_REFRESH`]).
    heard: Instant,
}

/// The bridge's state.
struct Bridge {
    common: Common,
    policy: Policy,
    link: Link,
    read_tx: mpsc::Sender<Read>,
    /// This site's devices, by id (pinned to the participant first heard).
    devices: HashMap<DeviceId, LocalDevice>,
    /// A second participant's DeviceInfo for a pinned id (a device restarted before its old
    /// participant was lost): it takes the id when the pinned one leaves.
    claims: HashMap<DeviceId, (ParticipantId, DeviceInfo)>,
    /// Other sites' devices here.
    proxies: HashMap<DeviceId, Proxy>,
    /// The proxies' participants (what the bridge hears from them is not this site's).
    ours: HashMap<ParticipantId, DeviceId>,
    /// Sites whose bridge is up.
    up: BTreeSet<SiteName>,
    /// Sites whose link went: their devices leave unless they are back within the grace.
    away: Absences,
    clock: Clock,
    /// Local command writers the vehicles' proxies heard: their operator and strength (a
    /// release names neither).
    writers: HashMap<GUID, (DeviceId, Strength)>,
    /// When this site's DeviceInfo was last sent again to every site.
    refreshed: Instant,
    refused: RateLimited,
    ignored: RateLimited,
    dropped_seen: u64,
    /// When configured sites not connected were last reported.
    missing: Instant,
    /// Sites just up, shown everything again at these instants.
    reshow: HashMap<SiteName, Instant>,
    /// A secured site's identities (`[security]`).
    secured: Option<Secured>,
    /// The revoked sites.
    revoked: Revocations,
}

/// The devices of `map` not heard (`heard`) for three DeviceInfo refreshes.
fn not_heard<T>(map: &HashMap<DeviceId, T>, heard: impl Fn(&T) -> Instant) -> Vec<DeviceId> {
    (map.iter())
        .filter(|(_, v)| heard(v).elapsed() > crate::dds::OFFLINE_AFTER)
        .map(|(id, _)| *id)
        .collect()
}

/// How long after a site comes up it is shown everything again.
const RESHOW: Duration = Duration::from_secs(1);

/// How often configured sites that are not connected are reported (first after one period).
const MISSING_REPORT: Duration = Duration::from_secs(5);

impl Bridge {
    fn new(
        common: Common,
        policy: Policy,
        link: Link,
        read_tx: mpsc::Sender<Read>,
        (revoked, secured): (Revocations, Option<Secured>),
    ) -> Bridge {
        Bridge {
            common,
            policy,
            link,
            read_tx,
            devices: HashMap::new(),
            claims: HashMap::new(),
            proxies: HashMap::new(),
            ours: HashMap::new(),
            up: BTreeSet::new(),
            away: Absences::new(),
            clock: Clock::start(),
            writers: HashMap::new(),
            refreshed: Instant::now(),
            refused: RateLimited::new("refused a message of another site"),
            ignored: RateLimited::new("ignored a local message"),
            dropped_seen: 0,
            missing: Instant::now(),
            reshow: HashMap::new(),
            secured,
            revoked,
        }
    }

    fn key(&self, to: &SiteName, subject: Subject) -> Key {
        Key {
            to: to.clone(),
            from: self.policy.me.clone(),
            subject,
        }
    }

    /// The sites up that see our device `info`.
    fn audience(&self, info: &DeviceInfo) -> Vec<SiteName> {
        (self.policy.peers.iter())
            .filter(|p| self.up.contains(&p.name) && self.policy.shows(p, info))
            .map(|p| p.name.clone())
            .collect()
    }

    /// Sends `payload` (`None`: a delete) about our device `info` to every site up that sees it.
    async fn tell(&self, info: &DeviceInfo, subject: Subject, payload: Option<Vec<u8>>) {
        for to in self.audience(info) {
            self.link
                .send(&self.key(&to, subject), payload.clone())
                .await;
        }
    }

    /// Sites up, other sites' devices here, this site's devices: what the status line shows.
    fn counts(&self) -> (usize, usize, usize) {
        (self.up.len(), self.proxies.len(), self.devices.len())
    }

    /// The `STATUS=` line: e.g. `site lab: 1 of 2 sites up (office not connected); 2 devices
    /// of other sites here, 3 on this site`.
    fn status_line(&self) -> String {
        let not_connected = match self.missing().as_slice() {
            [] => String::new(),
            names => format!(" ({} not connected)", names.join(", ")),
        };
        format!(
            "site {}: {} of {} sites up{not_connected}; {} devices of other sites here, {} on \
             this site",
            self.policy.me,
            self.up.len(),
            self.policy.peers.len(),
            self.proxies.len(),
            self.devices.len()
        )
    }

    /// The configured sites that are not up.
    fn missing(&self) -> Vec<&str> {
        (self.policy.peers.iter())
            .filter(|p| !self.up.contains(&p.name))
            .map(|p| p.name.as_str())
            .collect()
    }

    /// Whether our device `id` is pinned to `participant`.
    fn pinned(&self, id: DeviceId, participant: ParticipantId) -> bool {
        (self.devices.get(&id)).is_some_and(|d| d.participant == participant)
    }

    // ---- this site's network -------------------------------------------------------------

    async fn local(&mut self, heard: Heard) {
        match heard {
            Heard::Info { from, .. }
            | Heard::InfoGone { from, .. }
            | Heard::Status { from, .. }
            | Heard::Request { from, .. }
                if self.ours.contains_key(&from) => {}
            Heard::Info { info, from } => self.local_info(info, from).await,
            Heard::InfoGone { id, from } => {
                if self.claims.get(&id).is_some_and(|(p, _)| *p == from) {
                    self.claims.remove(&id);
                }
                if self.pinned(id, from) {
                    self.local_gone(id).await;
                }
            }
            Heard::Status { status, from } => {
                let id = status.vehicle_id;
                let Some(device) = self.devices.get_mut(&id) else {
                    return;
                };
                if device.participant != from {
                    return;
                }
                device.heard = Instant::now();
                if device.status.as_ref() == Some(&status) {
                    return;
                }
                device.status = Some(status.clone());
                let info = device.info.clone();
                self.tell(&info, Subject::Status(id), Some(wire::encode(&status)))
                    .await;
            }
            Heard::Request { msg, from } => self.local_request(msg, from).await,
            Heard::Lost(participant) => {
                let proxy_gone = (self.ours.get(&participant)).is_some_and(|id| {
                    self.proxies
                        .get(id)
                        .is_none_or(|p| p.participant() != participant)
                });
                if proxy_gone {
                    self.ours.remove(&participant);
                }
                self.claims.retain(|_, (p, _)| *p != participant);
                let gone: Vec<DeviceId> = (self.devices.iter())
                    .filter(|(_, d)| d.participant == participant)
                    .map(|(id, _)| *id)
                    .collect();
                for id in gone {
                    self.local_gone(id).await;
                }
                self.writers
                    .retain(|w, _| crate::dds::writer_id(*w).participant != participant);
            }
            Heard::Nothing => {}
        }
    }

    async fn local_info(&mut self, info: DeviceInfo, from: ParticipantId) {
        let id = info.device_id;
        if let Some(secured) = &self.secured
            && !secured.is_device(id, from)
        {
            self.ignored.warn(&format!(
                "participant {from} claims device {id}, which its certificate does not name"
            ));
            return;
        }
        if self.proxies.contains_key(&id) {
            self.ignored.warn(&format!(
                "device {id} here has the id of another site's device"
            ));
            return;
        }
        let full = self.devices.len() >= MAX_DEVICES;
        let changed = match self.devices.get_mut(&id) {
            Some(d) if d.participant != from => {
                self.ignored.warn(&format!(
                    "device {id} claimed by a second participant: it takes the id if the first \
                     leaves"
                ));
                if self.claims.len() < MAX_DEVICES || self.claims.contains_key(&id) {
                    self.claims.insert(id, (from, info));
                }
                return;
            }
            Some(d) => {
                let changed = d.info != info;
                d.info = info.clone();
                d.heard = Instant::now();
                changed
            }
            None if full => return,
            None => {
                info!(id, name = %info.name, kind = ?info.device_type, "device on this site");
                let device = LocalDevice {
                    participant: from,
                    info: info.clone(),
                    status: None,
                    heard: Instant::now(),
                };
                self.devices.insert(id, device);
                true
            }
        };
        if changed {
            self.tell(&info, Subject::Info(id), Some(wire::encode(&info)))
                .await;
        }
    }

    async fn local_gone(&mut self, id: DeviceId) {
        let Some(device) = self.devices.remove(&id) else {
            return;
        };
        info!(id, "device left this site");
        self.tell(&device.info, Subject::Info(id), None).await;
        // A device that restarted before its old participant was lost.
        if let Some((participant, info)) = self.claims.remove(&id) {
            self.local_info(info, participant).await;
        }
    }

    /// A local RequestControl goes to the sites of the devices it names.
    async fn local_request(&mut self, msg: RequestControl, from: ParticipantId) {
        let sender = msg.sender_id();
        if !self.pinned(sender, from) {
            self.ignored.warn(&format!(
                "RequestControl for {sender} from another participant"
            ));
            return;
        }
        let mut sites = BTreeSet::new();
        for id in [msg.src_id, msg.dest_id, msg.current_controller_id] {
            if let Some(p) = self.proxies.get(&id) {
                sites.insert(p.site.clone());
            }
        }
        let payload = wire::encode(&msg);
        for to in sites {
            let key = self.key(&to, Subject::Request(sender));
            self.link.send(&key, Some(payload.clone())).await;
        }
    }

    /// A command a vehicle's proxy read: from one of our operators, to that vehicle's site.
    async fn read(&mut self, read: Read) {
        let participant = crate::dds::writer_id(read.writer).participant;
        if self.ours.contains_key(&participant) {
            return;
        }
        // Whether a command's operator is pinned to the writer's participant (a release names
        // no operator: its writer's earlier commands did).
        let pinned = match &read.sample {
            Sample::Value(crate::dds::KeyedControlCommand(c)) => self.pinned(c.src_id, participant),
            Sample::Dispose(_) => true,
        };
        let Some(proxy) = self.proxies.get_mut(&read.vehicle) else {
            return;
        };
        let (src, strength, payload) = match read.sample {
            Sample::Value(crate::dds::KeyedControlCommand(command)) => {
                let src = command.src_id;
                if !pinned || command.dest_id != read.vehicle {
                    self.ignored
                        .warn(&format!("command as {src} from another participant"));
                    return;
                }
                let Some(strength) = proxy.strength_of(read.writer) else {
                    self.ignored
                        .warn(&"command of a writer whose strength is not known yet");
                    return;
                };
                if self.writers.len() < MAX_DEVICES || self.writers.contains_key(&read.writer) {
                    self.writers.insert(read.writer, (src, strength));
                }
                let payload = wire::encode(&wire::Command {
                    command,
                    stamp: read.stamp,
                });
                (src, strength, Some(payload))
            }
            Sample::Dispose(_) => match self.writers.get(&read.writer) {
                Some(&(src, strength)) => (src, strength, None),
                None => return,
            },
        };
        let subject = Subject::Command {
            src,
            dest: read.vehicle,
            strength,
        };
        let site = proxy.site.clone();
        let key = self.key(&site, subject);
        self.link.send(&key, payload).await;
    }

    // ---- the link ------------------------------------------------------------------------

    async fn arrived(&mut self, arrived: Arrived) {
        match arrived {
            Arrived::Message { key, put } => {
                if let Err(why) = self.message(&key, put) {
                    self.refused.warn(&format!("{key}: {why}"));
                }
            }
            Arrived::Site { site, up } if self.policy.peer(&site).is_some() => {
                self.site(site, up).await;
            }
            Arrived::Site { .. } => {}
        }
    }

    // ---- time ----------------------------------------------------------------------------

    async fn tick(&mut self) {
        self.cut_off_revoked();
        self.leave_due();
        for proxy in self.proxies.values() {
            proxy.refresh();
        }
        // A proxy whose site has said nothing of it for three refreshes is gone (a backstop:
        // deletes and the site's token normally say so first).
        for id in not_heard(&self.proxies, |p| p.heard) {
            self.drop_proxy(id);
        }
        // Likewise a local device not heard for three refreshes, as device lists and id pins
        // do (a backstop for a participant whose loss discovery never reports).
        for id in not_heard(&self.devices, |d| d.heard) {
            warn!(
                id,
                silent_s = crate::dds::OFFLINE_AFTER.as_secs(),
                "device on this site not heard: taken as gone"
            );
            self.local_gone(id).await;
        }
        let now = Instant::now();
        let due: Vec<SiteName> = (self.reshow.iter())
            .filter(|(_, at)| **at <= now)
            .map(|(site, _)| site.clone())
            .collect();
        for site in due {
            self.reshow.remove(&site);
            if self.up.contains(&site) {
                self.show_all(&site).await;
            }
        }
        if self.refreshed.elapsed() >= crate::dds::DEVICE_INFO_REFRESH {
            self.refreshed = Instant::now();
            let up: Vec<SiteName> = self.up.iter().cloned().collect();
            for site in up {
                self.show_all(&site).await;
            }
        }
        if self.missing.elapsed() >= MISSING_REPORT {
            self.missing = Instant::now();
            let missing = self.missing();
            if !missing.is_empty() {
                warn!(
                    sites = ?missing,
                    "not connected: the site's bridge is down or unreachable, or one of the two \
                     refused the other's certificate (the fleet's CA, common name \
                     rove-site-NAME, and the listening site's address in its certificate)"
                );
            }
        }
        let dropped = self.link.dropped.load(std::sync::atomic::Ordering::Relaxed);
        if dropped > self.dropped_seen {
            warn!(
                dropped = dropped - self.dropped_seen,
                "the loop fell behind the link"
            );
            self.dropped_seen = dropped;
        }
    }

    async fn leave(mut self) {
        let ids: Vec<DeviceId> = self.proxies.keys().copied().collect();
        for id in ids {
            self.drop_proxy(id);
        }
        self.link.close().await;
    }
}
