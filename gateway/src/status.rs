//! `rove status`: joins the domain read-only and shows the devices and who drives what.
//!
//! Devices come from DeviceInfo: TRANSIENT_LOCAL gives a late joiner every live device's last
//! sample at once, and a graceful exit disposes it. Presence is the participant's: one whose
//! SPDP lease runs out (a crash, a lost link) takes its devices offline (`ParticipantLost`,
//! within about 1.25 s at the default `presence_ms`); a device not heard for three DeviceInfo
//! refreshes is shown offline too, a backstop. The same device id from two processes is reported as a
//! duplicate, never merged: the row shows what the participant the id is pinned to says
//! (docs/design.md §4b), and the warning names every participant that claimed it.

use crate::dds::{self, Domain, KeyedDeviceInfo, KeyedVehicleStatus};
use futures::StreamExt;
use rove_console::model::VehicleView;
use rove_console::standing::{Standing, standing};
use rove_console::view::mode_name;
use rove_core::arbiter::ParticipantId;
use rove_core::msg::{
    DeviceId, DeviceInfo, DeviceType, Mode, OutputState, VehicleHealth, VehicleStatus,
};
use rove_core::trust::{Identities, TrustConfig};
use rustdds::with_key::Sample;
use serde::Serialize;
use std::collections::{BTreeMap, BTreeSet};
use std::net::Ipv4Addr;
use std::time::{Duration, Instant};

/// One device as seen by `rove status`.
#[derive(Debug, Clone, Serialize)]
pub struct DeviceRow {
    /// Device id.
    pub id: DeviceId,
    /// Name.
    pub name: String,
    /// The site of another site's device (its name ends with ` @SITE`, docs/remote.md).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub site: Option<String>,
    /// "vehicle" or "controller".
    #[serde(rename = "type")]
    pub kind: &'static str,
    /// Vehicles: who drives it (its own id = failsafe).
    pub controller_id: DeviceId,
    /// Not withdrawn, its participant present, heard within three DeviceInfo refreshes.
    pub online: bool,
    /// Milliseconds since its last DeviceInfo.
    pub last_seen_ms: u64,
    /// Vehicles, from their VehicleStatus: the mode last applied.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mode: Option<&'static str>,
    /// Vehicles, from their VehicleStatus: the output's health (`ok`, `hung: …`, `down: …`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub output: Option<String>,
    /// Vehicles, from their VehicleStatus: the outputs are in the safe state.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub failsafe: Option<bool>,
    /// Vehicles: where it stands for a bystander (`offline`, `failsafe`, `held`, `driven`:
    /// someone drives), as every console derives it (rove_console::standing).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub standing: Option<&'static str>,
    /// Vehicles: the same in words, e.g. `"held by autopilot · owner 11"`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub standing_text: Option<String>,
    /// Vehicles, from their VehicleStatus: battery and autopilot (as the local API gives them).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub health: Option<serde_json::Value>,
    /// The standing and health, for the table.
    #[serde(skip)]
    view: Option<(Standing, VehicleHealth)>,
}

/// A snapshot of the domain.
#[derive(Debug, Clone, Serialize)]
pub struct Snapshot {
    /// Every device seen, by id.
    pub devices: Vec<DeviceRow>,
    /// Ids announced by more than one process.
    pub duplicates: Vec<DeviceId>,
    /// For each duplicate id: who claimed it, the believed participant first.
    pub claims: Vec<Claim>,
}

/// A device id claimed by more than one participant.
#[derive(Debug, Clone, Serialize)]
pub struct Claim {
    /// The id.
    pub id: DeviceId,
    /// The participant it is pinned to (its DeviceInfo is the one shown).
    pub believed: String,
    /// The others that claimed it.
    pub others: Vec<String>,
}

#[derive(Debug)]
struct Seen {
    info: DeviceInfo,
    at: Instant,
    withdrawn: bool,
    /// The participant the row's info comes from (the id's pin).
    believed: ParticipantId,
    /// Every participant that claimed the id (at most [`MAX_CLAIMANTS`]).
    participants: BTreeSet<ParticipantId>,
}

/// Most devices `rove status` remembers: a fleet has tens. Beyond it, a new id takes the place of
/// the device withdrawn or silent longest, or, with none such, is not listed (a flood of
/// invented ids cannot grow the table).
pub const MAX_DEVICES: usize = 1024;

/// Most participants remembered as claiming one id (the report of a duplicate names them).
pub const MAX_CLAIMANTS: usize = 8;

/// Whether `seen` may hold `id`, making room if it must by forgetting the device that has been
/// withdrawn or silent for `offline_after` the longest.
fn has_room(seen: &mut BTreeMap<DeviceId, Seen>, id: DeviceId, offline_after: Duration) -> bool {
    if seen.len() < MAX_DEVICES || seen.contains_key(&id) {
        return true;
    }
    let oldest = (seen.iter())
        .filter(|(_, s)| s.withdrawn || s.at.elapsed() >= offline_after)
        .min_by_key(|(_, s)| s.at)
        .map(|(id, _)| *id);
    oldest.is_some_and(|old| seen.remove(&old).is_some())
}

/// Options of `rove status`.
#[derive(Debug, Clone)]
pub struct Options {
    /// DDS domain.
    pub domain_id: u16,
    /// Interfaces.
    pub interfaces: Vec<Ipv4Addr>,
    /// How long to listen before a snapshot.
    pub listen: Duration,
    /// Print JSON instead of a table.
    pub json: bool,
    /// Keep printing.
    pub watch: bool,
    /// Join a secured fleet with the DDS Security files in this directory (`rove keys add`).
    pub security: Option<std::path::PathBuf>,
    /// Print every DeviceInfo and RequestControl sample as a JSON line with its arrival time
    /// (for benchmarks and scripts), instead of snapshots.
    pub events: bool,
}

/// Runs `rove status`.
///
/// # Errors
/// The participant or reader cannot be created.
pub async fn run(options: Options) -> anyhow::Result<()> {
    let domain = Domain::join(
        options.domain_id,
        &options.interfaces,
        options.security.as_deref(),
        false,
        dds::DEFAULT_PRESENCE,
    )?;
    let mut samples = domain.device_info_reader()?.async_sample_stream();
    let mut requests = domain.request_reader()?.async_sample_stream();
    let mut statuses = domain.vehicle_status_reader()?.async_sample_stream();
    let mut vehicles: BTreeMap<DeviceId, VehicleStatus> = BTreeMap::new();
    let clock = crate::runtime::Clock::start();
    let mut seen: BTreeMap<DeviceId, Seen> = BTreeMap::new();
    let mut ids = Identities::new(TrustConfig {
        hold: dds::OFFLINE_AFTER,
        ..TrustConfig::default()
    });
    let discovery = domain.participant.status_listener();
    let mut discovery = rustdds::StatusEvented::as_async_status_stream(&discovery);
    let mut next_print = tokio::time::Instant::now() + options.listen;
    // SIGTERM or SIGINT ends the watch with the participant dropped, which tells every peer it
    // left (a killed one stays matched, and heartbeated, for rustdds's 50 s lease).
    let shutdown = crate::runtime::shutdown_signal()?;
    tokio::pin!(shutdown);
    loop {
        tokio::select! {
            () = &mut shutdown => return Ok(()),
            sample = samples.next() => match sample {
                Some(Ok(s)) => {
                    let from = dds::writer_id(s.sample_info().writer_guid()).participant;
                    match s.into_value() {
                        Sample::Value(KeyedDeviceInfo(info)) => {
                            let believed = ids.claim(clock.now(), info.device_id, from).is_ok();
                            if !has_room(&mut seen, info.device_id, dds::OFFLINE_AFTER) {
                                continue;
                            }
                            let entry = seen.entry(info.device_id).or_insert_with(|| Seen {
                                info: info.clone(), at: Instant::now(), withdrawn: false,
                                believed: from, participants: BTreeSet::new(),
                            });
                            if entry.participants.len() < MAX_CLAIMANTS {
                                entry.participants.insert(from);
                            }
                            if !believed {
                                continue;
                            }
                            if options.events {
                                println!("{}", serde_json::json!({
                                    "wall_us": clock.wall_micros(), "kind": "device",
                                    "id": info.device_id, "controller_id": info.controller_id,
                                }));
                            }
                            entry.info = info;
                            entry.at = Instant::now();
                            entry.withdrawn = false;
                            entry.believed = from;
                        }
                        Sample::Dispose(id) => {
                            if let Some(entry) = seen.get_mut(&id) {
                                entry.participants.remove(&from);
                                if entry.believed == from {
                                    entry.withdrawn = true;
                                }
                            }
                        }
                    }
                }
                Some(Err(_)) => {} // malformed sample: not a device we can show
                None => anyhow::bail!("DeviceInfo stream ended"),
            },
            status = statuses.next() => match status {
                Some(Ok(s)) => {
                    let from = dds::writer_id(s.sample_info().writer_guid()).participant;
                    match s.into_value() {
                        // Believed from the participant the vehicle's id is pinned to.
                        Sample::Value(KeyedVehicleStatus(status)) => {
                            if ids.claim(clock.now(), status.vehicle_id, from).is_ok() {
                                vehicles.insert(status.vehicle_id, status);
                            }
                        }
                        Sample::Dispose(id) => {
                            if ids.claim(clock.now(), id, from).is_ok() {
                                vehicles.remove(&id);
                            }
                        }
                    }
                }
                Some(Err(_)) => {} // malformed sample
                None => anyhow::bail!("VehicleStatus stream ended"),
            },
            Some(event) = discovery.next() => {
                if let rustdds::DomainParticipantStatusEvent::ParticipantLost { id, .. } = event {
                    let gone = dds::participant_id(id.as_ref());
                    participant_left(&mut seen, &mut ids, clock.now(), gone);
                }
            }
            request = requests.next() => match request {
                Some(Ok(s)) if options.events => {
                    let rc = s.value();
                    println!("{}", crate::runtime::request_json(&clock, rc));
                }
                Some(_) => {}
                None => anyhow::bail!("RequestControl stream ended"),
            },
            _ = tokio::time::sleep_until(next_print), if !options.events => {
                let snap = snapshot(&seen, &vehicles, dds::OFFLINE_AFTER);
                if options.json {
                    println!("{}", serde_json::to_string(&snap)?);
                } else {
                    print!("{}", table(&snap));
                }
                if !options.watch {
                    return Ok(());
                }
                next_print += Duration::from_secs(1);
            }
        }
    }
}

/// A participant that left (its lease ran out, or it said goodbye) takes the devices it spoke
/// for offline, and its pins lapse after the grace.
fn participant_left(
    seen: &mut BTreeMap<DeviceId, Seen>,
    ids: &mut Identities,
    now: rove_core::MonoTime,
    gone: ParticipantId,
) {
    ids.participant_gone(now, gone);
    for entry in seen.values_mut() {
        entry.participants.remove(&gone);
        if entry.believed == gone {
            entry.withdrawn = true;
        }
    }
}

/// `"name (id)"` for a device `rove status` knows, else the id.
fn label(seen: &BTreeMap<DeviceId, Seen>, id: DeviceId) -> String {
    match seen.get(&id) {
        Some(s) => format!("{} ({id})", s.info.name),
        None => id.to_string(),
    }
}

fn snapshot(
    seen: &BTreeMap<DeviceId, Seen>,
    vehicles: &BTreeMap<DeviceId, VehicleStatus>,
    offline_after: Duration,
) -> Snapshot {
    let devices = seen
        .values()
        .map(|s| {
            let status = vehicles.get(&s.info.device_id);
            let output = status.map(output_text);
            let online = !s.withdrawn && s.at.elapsed() < offline_after;
            let view = (s.info.device_type == DeviceType::Vehicle).then(|| {
                let id = s.info.device_id;
                let view = VehicleView {
                    owner: s.info.controller_id,
                    mode: status.map(|v| v.mode),
                    failsafe: status.is_some_and(|v| v.failsafe),
                    link: output.clone(),
                    status_owner: status.map(|v| v.controller_id),
                    output: status.map(|v| v.output),
                    health: status.map(|v| v.health.clone()).unwrap_or_default(),
                };
                (standing(id, online, &view, None, None), view.health)
            });
            DeviceRow {
                id: s.info.device_id,
                name: s.info.name.clone(),
                site: rove_core::site::site_of_name(&s.info.name).map(|s| s.to_string()),
                kind: match s.info.device_type {
                    DeviceType::Vehicle => "vehicle",
                    DeviceType::Controller => "controller",
                },
                controller_id: s.info.controller_id,
                online,
                last_seen_ms: u64::try_from(s.at.elapsed().as_millis()).unwrap_or(u64::MAX),
                mode: status.map(|v| mode_name(v.mode)),
                output,
                failsafe: status.map(|v| v.failsafe),
                standing: view.as_ref().map(|(st, _)| st.kind()),
                standing_text: (view.as_ref()).map(|(st, _)| st.text(|id| label(seen, id))),
                health: status.map(|v| rove_console::api::health_json(&v.health)),
                view,
            }
        })
        .collect();
    let claims: Vec<Claim> = seen
        .values()
        .filter(|s| s.participants.len() > 1)
        .map(|s| Claim {
            id: s.info.device_id,
            believed: s.believed.to_string(),
            others: (s.participants.iter())
                .filter(|p| **p != s.believed)
                .map(ToString::to_string)
                .collect(),
        })
        .collect();
    Snapshot {
        devices,
        duplicates: claims.iter().map(|c| c.id).collect(),
        claims,
    }
}

/// Columns of `rove status`'s table (the console's widths).
const TABLE_WIDTH: u16 = 140;

/// The human table: one row per device, vehicles showing who drives them. The same rendering
/// as the operator console's device table (rove-console), printed as text.
pub fn table(snap: &Snapshot) -> String {
    use rove_console::model::DeviceKind;
    let rows: Vec<rove_console::DeviceRow> = snap
        .devices
        .iter()
        .map(|d| rove_console::DeviceRow {
            id: d.id,
            name: d.name.clone(),
            kind: DeviceKind::from_name(d.kind).unwrap_or(DeviceKind::Controller),
            online: d.online,
            age: Duration::from_millis(d.last_seen_ms),
            standing: (d.view.as_ref())
                .map(|(s, _)| (s.clone(), d.standing_text.clone().unwrap_or_default())),
            mode: (d.mode).and_then(|m| Mode::ALL.into_iter().find(|x| mode_name(*x) == m)),
            health: d.view.as_ref().map(|(_, h)| h.clone()),
            link: d.output.clone(),
            selected: false,
        })
        .collect();
    let mut out = rove_console::view::status_text(&rows, TABLE_WIDTH);
    out.push('\n');
    for claim in &snap.claims {
        out.push_str(&format!(
            "warning: device id {} is used by more than one process: shown as participant {} \
             says; also claimed by {}\n",
            claim.id,
            claim.believed,
            claim.others.join(", ")
        ));
    }
    out
}

/// A vehicle's output health in a few words: `ok` (with an autopilot's mode), `down: …`,
/// `hung: …`.
pub fn output_text(status: &VehicleStatus) -> String {
    match status.output {
        OutputState::Hung => format!("hung: {}", status.detail),
        _ => status.detail.clone(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn seen(id: DeviceId, silent_for: Duration) -> Seen {
        Seen {
            info: DeviceInfo {
                device_id: id,
                name: format!("d{id}"),
                device_type: DeviceType::Controller,
                controller_id: id,
            },
            at: Instant::now()
                .checked_sub(silent_for)
                .unwrap_or_else(Instant::now),
            withdrawn: false,
            believed: ParticipantId(1),
            participants: BTreeSet::new(),
        }
    }

    #[test]
    fn the_device_table_is_bounded_and_only_silent_devices_make_room() {
        let offline_after = Duration::from_secs(3);
        let mut table: BTreeMap<DeviceId, Seen> = (0..MAX_DEVICES as DeviceId)
            .map(|id| (id, seen(id, Duration::ZERO)))
            .collect();
        // Full of live devices: a newcomer is not listed, a known device still is.
        assert!(!has_room(&mut table, 5_000, offline_after));
        assert!(has_room(&mut table, 7, offline_after));
        // One falls silent (and one is withdrawn): each makes room once, the silent one first.
        table.insert(3, seen(3, Duration::from_secs(10)));
        table.entry(4).and_modify(|s| s.withdrawn = true);
        for (newcomer, forgotten) in [(5_000, 3), (5_001, 4)] {
            assert!(has_room(&mut table, newcomer, offline_after));
            assert!(!table.contains_key(&forgotten), "{forgotten} kept");
            table.insert(newcomer, seen(newcomer, Duration::ZERO));
        }
        assert!(!has_room(&mut table, 5_002, offline_after));
        assert_eq!(table.len(), MAX_DEVICES);
    }
}
