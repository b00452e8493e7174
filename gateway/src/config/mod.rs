//! Configuration files: one TOML file per device (docs/design.md §7).
//!
//! Two stages: the raw serde structs below reject unknown keys and only parse; `validate()`
//! turns them into [`VehicleConfig`] / [`OperatorConfig`], collecting every problem. Every error
//! names the file, the line and the key: `vehicle.toml:7: vehicle.command_timeout_ms = 0: …`.
//! An absent key takes its default quietly; a present but invalid key is an error.
//!
//! # Layout
//! - this file: the sections every role shares (`[device]`, `[network]`, `[log]`,
//!   `[security]`), [`Common`], and loading a file of any role;
//! - `vehicle.rs`, `operator.rs`, `web.rs`, `bridge.rs`: each role's file;
//! - `output.rs`: the list of output adapters and `[output]` read through it;
//! - `locate.rs`: reading a file, and naming the line of a key in errors.

mod bridge;
mod locate;
mod operator;
mod output;
mod vehicle;
mod web;

pub use bridge::*;
pub use locate::key_line;
use locate::*;
pub use operator::*;
pub use output::*;
pub use vehicle::*;
pub use web::*;

use anyhow::{Context, anyhow};
use rove_core::arbiter::ArbiterConfig;
use rove_core::config::{ABSENT, Int, Unique};
use rove_core::error::ConfigErrors;
use rove_core::handover::{HandoverConfig, HandoverSettings};
use rove_core::hierarchy::{DeviceClass, Hierarchy, HierarchyTable, Level, Strength};
use rove_core::msg::{DeviceId, Mode, MovementCommand};
use rove_core::trust::{Access, Grant, TrustConfig};
use rove_core::watchdog::CommandTimeout;
use serde::{Deserialize, Serialize};
use std::net::Ipv4Addr;
use std::path::Path;
#[cfg(test)]
use std::path::PathBuf;
use std::time::Duration;

rove_core::config_types! {
    /// `[device]`.
    pub table DeviceSection {
        id: DeviceId => "This device's id on the network; unique per device.",
        name: Option<String> => "Human-readable name (absent: `rove-<id>`).",
    }

    /// `[network]`.
    pub table NetworkSection {
        domain_id: Option<Int> => "DDS domain id (absent: 0).",
        interfaces: Option<Vec<Ipv4Addr>> => "IPv4 addresses of the interfaces DDS may use \
            (absent: loopback only).",
        heartbeat_ms: Option<Int> => "How often the role checks its state (`STATUS=`, \
            VehicleStatus, DeviceInfo changes), ms (absent: 500). DeviceInfo goes out on a change \
            and otherwise every 5 s.",
        presence_ms: Option<Int> => "SPDP announcement period, ms, 250 to 500 (absent: 250). \
            The participant lease announced is four periods: a crashed device leaves every list \
            within five periods. The announcements also assert the DeviceInfo writer's 1 s \
            liveliness for foreign readers (docs/design.md, \"Fleet scale\").",
    }

    /// `[log]`.
    pub table LogSection {
        level: Option<String> => "A level (`error`, `warn`, `info`, `debug`, `trace`) or tracing \
            filter directives such as `\"info,rove_gateway=debug\"` (absent: `info`). rustdds \
            stays at `warn` unless a directive names it (its `info` is very chatty). `RUST_LOG`, \
            when set, overrides all of this.",
    }

    /// `[security]`: join as an authenticated participant (DDS Security, docs/security.md).
    pub table SecuritySection {
        dir: std::path::PathBuf => "This device's directory from `rove keys add` (relative \
            paths: to the config file): identity CA, certificate, private key, permissions CA, \
            governance and permissions.",
    }

    /// Validated identity and network settings, shared by both roles.
    #[derive(Debug, Clone, PartialEq, Eq)]
    pub struct Common {
        id: DeviceId => "Device id.",
        name: String => "Device name.",
        domain_id: u16 => "DDS domain.",
        interfaces: Vec<Ipv4Addr> => "Interfaces DDS is confined to.",
        heartbeat: Duration => "Presence heartbeat period.",
        presence: Duration => "`[network] presence_ms`: the SPDP period.",
        log_filter: Option<String> => "The log filter from `[log] level`, if any.",
        security: Option<std::path::PathBuf> => "`[security] dir`: join authenticated, with the \
            DDS Security files there.",
    }
}

impl Common {
    /// Makes a relative `[security] dir` relative to the config file's directory.
    pub fn resolve_paths(&mut self, config_path: &Path) {
        let dir = config_path.parent().unwrap_or(Path::new("."));
        // Joined to an absolute path, `dir` is dropped.
        if let Some(security) = &mut self.security {
            *security = dir.join(&*security);
        }
    }

    /// What the DDS layer needs to join as this device.
    pub fn node(&self) -> crate::dds::NodeSettings {
        crate::dds::NodeSettings {
            id: self.id,
            name: self.name.clone(),
            domain_id: self.domain_id,
            interfaces: self.interfaces.clone(),
            presence: self.presence,
            security: self.security.clone(),
        }
    }

    /// How long device ids stay pinned to their participants: until one heartbeat after the
    /// participant left the domain (its lease ran out or it said goodbye), and at most three
    /// DeviceInfo refreshes after the device's last message (a backstop, as in the lists).
    pub fn trust(&self) -> TrustConfig {
        TrustConfig {
            hold: crate::dds::OFFLINE_AFTER,
            grace: self.heartbeat,
            ..TrustConfig::default()
        }
    }
}

rove_core::config_types! {
    /// A config file, either role, for `rove check-config`.
    #[derive(Debug)]
    pub enum AnyConfig {
        Vehicle => "A vehicle's file." (VehicleConfig),
        Operator => "An operator's file." (OperatorConfig),
        Bridge => "A site bridge's file." (BridgeConfig),
    }
}

/// Loads a file of either role, telling them apart by their `[vehicle]`/`[output]` or
/// `[operator]` table; also returns the effective config: the file's settings with every
/// default filled in, as TOML that loads again as the same config.
///
/// # Errors
/// As [`load_vehicle`]; also when the file has neither role's table.
pub fn load_any(path: &Path) -> anyhow::Result<(AnyConfig, String)> {
    any_from_text(path, &read(path)?)
}

/// [`load_any`] of `text`, read from `path` (`path` only names the file in messages; nothing
/// is read). Public for the fuzz targets, which feed every config kind through it.
///
/// # Errors
/// As [`load_any`].
pub fn any_from_text(path: &Path, text: &str) -> anyhow::Result<(AnyConfig, String)> {
    let table: toml::Table = toml::from_str(text)
        .map_err(|e| anyhow!("{}: {}", path.display(), e.to_string().trim_end()))?;
    let located = |e| located(path, text, e);
    let (config, effective) = if table.contains_key("zenoh") {
        let mut raw: RawBridge = parse(path, text)?;
        let config = AnyConfig::Bridge(raw.validate().map_err(located)?);
        (config, toml::to_string(&raw))
    } else if table.contains_key("operator") {
        let mut raw: RawOperator = parse(path, text)?;
        let config = AnyConfig::Operator(raw.validate().map_err(located)?);
        (config, toml::to_string(&raw))
    } else if table.contains_key("output") || table.contains_key("vehicle") {
        let mut raw = parse_vehicle(path, text)?;
        let config = AnyConfig::Vehicle(raw.validate().map_err(located)?);
        (config, toml::to_string(&raw))
    } else {
        return Err(anyhow!(
            "{}: neither a vehicle config ([output]), an operator config ([operator]) nor a \
             bridge config ([zenoh])",
            path.display()
        ));
    };
    let effective = effective.context("cannot write the effective config as TOML")?;
    Ok((config, effective))
}

const DEFAULT_HEARTBEAT_MS: Int = 500;
const DEFAULT_STREAM_HZ: Int = 50;

fn validate_common(
    device: &mut DeviceSection,
    network: &mut NetworkSection,
    log: &LogSection,
    errors: &mut ConfigErrors,
) -> Common {
    let heartbeat_ms = *network.heartbeat_ms.get_or_insert(DEFAULT_HEARTBEAT_MS);
    let heartbeat = errors.int("network.heartbeat_ms", heartbeat_ms, 50..=10_000, "");
    // At most half the DeviceInfo writer's 1 s lease, which the announcements assert for
    // foreign readers; at least the 250 ms at which liveness is reported.
    let default_presence = crate::dds::DEFAULT_PRESENCE.as_millis() as Int;
    let presence_ms = *network.presence_ms.get_or_insert(default_presence);
    let rule = " (at least the 250 ms liveness report period, at most half the DeviceInfo \
                writer's 1 s lease)";
    let presence = errors.int("network.presence_ms", presence_ms, 250..=500, rule);
    if device.id <= 0 {
        errors.add("device.id", device.id, "must be a positive device id");
    }
    let domain_id = *network.domain_id.get_or_insert(0);
    // RTPS maps domain ids to ports (7400 + 250 × domain); above 232 the ports overflow.
    let rule = " (RTPS port mapping)";
    let domain_id = errors.int("network.domain_id", domain_id, 0..=232, rule);
    if let Some(level) = &log.level
        && !is_log_filter(level)
    {
        let rule = "must be a level (off, error, warn, info, debug, trace) or comma-separated \
                    `target=level` directives";
        errors.add("log.level", format!("{level:?}"), rule);
    }
    let interfaces = (network.interfaces).get_or_insert_with(|| vec![Ipv4Addr::LOCALHOST]);
    if interfaces.is_empty() {
        let rule = "must name at least one interface address (absent: loopback)";
        errors.add("network.interfaces", "[]", rule);
    }
    let id = device.id;
    let name = device.name.get_or_insert_with(|| format!("rove-{id}"));
    let log_filter = |level: &String| match level.contains("rustdds") {
        true => level.clone(),
        false => format!("{level},rustdds=warn"),
    };
    Common {
        id,
        name: name.clone(),
        domain_id: domain_id.unwrap_or(0),
        interfaces: interfaces.clone(),
        heartbeat: Duration::from_millis(heartbeat.unwrap_or(500)),
        presence: presence.map_or(crate::dds::DEFAULT_PRESENCE, Duration::from_millis),
        log_filter: log.level.as_ref().map(log_filter),
        security: None,
    }
}

/// A log filter as `[log] level` takes it: levels and `target=level` directives. Stricter than
/// tracing's own parser, which takes a misspelt level for a target name and logs nothing.
fn is_log_filter(filter: &str) -> bool {
    const LEVELS: [&str; 6] = ["off", "error", "warn", "info", "debug", "trace"];
    let is_level = |l: &str| LEVELS.contains(&l.trim().to_ascii_lowercase().as_str());
    !filter.trim().is_empty()
        && filter.split(',').all(|d| match d.split_once('=') {
            Some((target, level)) => !target.trim().is_empty() && is_level(level),
            None => is_level(d),
        })
        && tracing_subscriber::EnvFilter::try_new(filter).is_ok()
}

/// The path of a config shipped in `configs/`.
#[cfg(test)]
pub fn shipped(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join("configs")
        .join(name)
}

#[cfg(test)]
mod tests;
