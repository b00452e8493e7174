//! Starting the scale bench's fleet: its ids, its DDS Security files when secured, the
//! processes, and the wait until every vehicle is driven by its laptop.

use super::owners::{Assignment, assign, drives_of, is_laptop};
use super::{FIRST_OPERATOR, FIRST_VEHICLE, Options, PHONE, PHONES};
use crate::harness::{self, Rig, wall_us};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

/// The fleet's `[network]` table: the heartbeat and presence the options ask for.
pub(super) fn network_toml(options: &Options) -> String {
    let heartbeat = options
        .heartbeat_ms
        .map(|ms| format!("heartbeat_ms = {ms}\n"));
    let presence = options
        .presence_ms
        .map(|ms| format!("presence_ms = {ms}\n"));
    match (heartbeat, presence) {
        (None, None) => String::new(),
        (h, p) => format!(
            "[network]\n{}{}",
            h.unwrap_or_default(),
            p.unwrap_or_default()
        ),
    }
}

/// The ids of the fleet.
pub(super) fn fleet_ids(options: &Options) -> (Vec<i64>, Vec<i64>) {
    let vehicles = (0..options.vehicles as i64).map(|k| FIRST_VEHICLE + k);
    let operators = (0..options.operators as i64).map(|i| FIRST_OPERATOR + i);
    (vehicles.collect(), operators.collect())
}

/// The id whose certificate `rove status` observers use in a secured fleet.
const OBSERVER: i64 = 9999;

/// The phone of handover run `run`.
pub(super) fn phone(run: usize) -> i64 {
    PHONE + (run as i64 % PHONES)
}

/// Every id that needs a certificate in a secured fleet.
fn certified_ids(options: &Options) -> Vec<i64> {
    let (vehicles, operators) = fleet_ids(options);
    (vehicles.into_iter().chain(operators))
        .chain((0..options.handover_runs).map(phone))
        .chain([OBSERVER])
        .collect()
}

/// A fleet's DDS Security files, if it is secured.
#[derive(Debug, Clone, Default)]
pub(super) struct Keys(Option<PathBuf>);

impl Keys {
    /// Makes them in the rig's directory when `options` asks for a secured fleet.
    pub(super) fn make(rig: &Rig, options: &Options) -> anyhow::Result<Keys> {
        let dir = options.secure.then(|| rig.fleet(&certified_ids(options)));
        Ok(Keys(dir.transpose()?))
    }

    /// Device `id`'s `[security]` table, empty unsecured.
    pub(super) fn toml(&self, id: i64) -> String {
        harness::security_toml(self.0.as_deref(), id)
    }
}

/// Starts `rove status --events` as `name`, secured like the fleet; its log is the event
/// stream.
pub(super) fn observer(rig: &mut Rig, keys: &Keys, name: &str) -> PathBuf {
    let dir = keys.0.as_ref().map(|f| f.join(OBSERVER.to_string()));
    let dir = dir.map(|d| d.display().to_string());
    let mut args = vec!["status", "--events"];
    if let Some(dir) = &dir {
        args.extend(["--security", dir.as_str()]);
    }
    let p = rig.spawn(name, &args);
    rig.procs[p].log.clone()
}

/// A fleet just started: who is who, and where each vehicle records.
pub(super) struct Started {
    pub(super) vehicles: Vec<i64>,
    pub(super) operators: Vec<i64>,
    /// Each vehicle's record, in the order of `vehicles`.
    pub(super) records: Vec<PathBuf>,
    pub(super) assignment: Assignment,
    /// Each operator's process index in the rig, and what it is started with.
    pub(super) started_as: BTreeMap<i64, (usize, &'static str, Vec<i64>)>,
    /// Wall clock of the first process's start, µs.
    pub(super) at: u64,
    /// The `[network]` and `[security]` an operator `id` is started with.
    pub(super) keys: Keys,
    pub(super) network: String,
}

impl Started {
    /// What operator `id` appends to its file: the fleet's `[network]` and its `[security]`.
    pub(super) fn extra(&self, id: i64) -> String {
        format!("{}{}", self.network, self.keys.toml(id))
    }
}

/// Starts the fleet's vehicles, then its operators, in `rig`.
pub(super) fn start(rig: &mut Rig, options: &Options) -> anyhow::Result<Started> {
    let keys = Keys::make(rig, options)?;
    let at = wall_us();
    let (vehicles, operators) = fleet_ids(options);
    let network = network_toml(options);
    // Only the measured vehicle runs real-time: on a real board each vehicle has its own
    // computer, and here the rest of the fleet plays the load on that board. (Every vehicle
    // real-time on these two cores starves the operators: measured, stale outputs everywhere.)
    let records: Vec<PathBuf> = (vehicles.iter())
        .map(|&v| {
            let fifo = options.vehicle_rt.filter(|_| v == FIRST_VEHICLE);
            let output = format!("{network}{}[output]\nadapter = \"sim\"\n", keys.toml(v));
            rig.vehicle_scheduled(v, &output, fifo)
        })
        .collect();
    let assignment = assign(&vehicles, &operators);
    let mut fleet = Started {
        vehicles,
        operators,
        records,
        assignment,
        started_as: BTreeMap::new(),
        at,
        keys,
        network,
    };
    for id in fleet.operators.clone() {
        let class = match is_laptop(&fleet.assignment, id) {
            true => "laptop",
            false => "desktop",
        };
        let drive = match options.idle {
            true => Vec::new(),
            false => drives_of(&fleet.assignment, id),
        };
        let extra = fleet.extra(id);
        let p = rig.operator(id, "stationary", class, &drive, 1000, &extra, &[]);
        fleet.started_as.insert(id, (p, class, drive));
    }
    Ok(fleet)
}

/// Waits at most `patience` until every vehicle of `f` has applied its laptop's command; how
/// long after the start the last one did (ms), or the vehicles that were never driven.
pub(super) fn driven(f: &Started, patience: Duration) -> Result<u64, Vec<i64>> {
    let give_up = Instant::now() + patience;
    let mut first: BTreeMap<i64, u64> = BTreeMap::new();
    loop {
        for (&vehicle, record) in f.vehicles.iter().zip(&f.records) {
            let Some(&(laptop, _)) = f.assignment.get(&vehicle) else {
                first.insert(vehicle, f.at);
                continue;
            };
            if first.contains_key(&vehicle) {
                continue;
            }
            let outs = harness::records(record);
            let by_laptop = outs
                .iter()
                .find(|o| o.action == "apply" && o.owner == Some(laptop));
            if let Some(o) = by_laptop {
                first.insert(vehicle, o.wall_us);
            }
        }
        if first.len() == f.vehicles.len() {
            let last = first.values().max().copied().unwrap_or(f.at);
            return Ok(last.saturating_sub(f.at) / 1000);
        }
        if Instant::now() > give_up {
            let undriven = f.vehicles.iter().filter(|v| !first.contains_key(v));
            return Err(undriven.copied().collect());
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}
