//! `[[output.gcs]]`: the ground stations rove routes the autopilot's link to, and those that are
//! operators of the hierarchy (`id`; docs/mavlink.md, "A ground station in the hierarchy").

use super::{Endpoint, GcsSettings, MavlinkSettings};
use crate::station::Feed;
use rove_core::config::Unique;
use rove_core::error::ConfigErrors;
use rove_core::hierarchy::{DeviceClass, Level};
use std::path::PathBuf;
use std::sync::Arc;

/// A validated `[[output.gcs]]`.
#[derive(Debug, Clone, PartialEq)]
pub struct GcsConfig {
    /// Where the station is.
    pub endpoint: Endpoint,
    /// The station as an operator of the hierarchy, if it has an `id`.
    pub station: Option<StationConfig>,
}

/// A ground station that is an operator of the hierarchy.
#[derive(Debug, Clone)]
pub struct StationConfig {
    /// Its device id.
    pub id: i64,
    /// Its MAVLink system id: only its frames speak for it.
    pub system_id: u8,
    /// Its name.
    pub name: String,
    /// Its level.
    pub level: Level,
    /// Its device class.
    pub class: DeviceClass,
    /// Its `[security]` files.
    pub security: Option<PathBuf>,
    /// What its port heard, shared with its operator loop (a copy of the config shares it).
    pub feed: Arc<Feed>,
}

/// Two configs are the same when they say the same; the feed is the running station's.
impl PartialEq for StationConfig {
    fn eq(&self, other: &StationConfig) -> bool {
        (
            self.id,
            self.system_id,
            &self.name,
            self.level,
            self.class,
            &self.security,
        ) == (
            other.id,
            other.system_id,
            &other.name,
            other.level,
            other.class,
            &other.security,
        )
    }
}

impl MavlinkSettings {
    pub(super) fn validate_gcs(
        &mut self,
        autopilot: &Endpoint,
        own_system: Option<u8>,
        errors: &mut ConfigErrors,
    ) -> Vec<GcsConfig> {
        let mut used = Unique::default();
        let mut ids = Unique::default();
        let mut out = Vec::new();
        for (i, g) in self.gcs.iter_mut().enumerate() {
            let owner = format!("gcs[{i}]");
            let gcs = errors.within(&owner, |ge| {
                g.unknown.check(ge, GcsSettings::KNOWN);
                let endpoint = endpoint(g, autopilot, &owner, &mut used, ge)?;
                let station = station(g, &endpoint, own_system, &owner, &mut ids, ge);
                Some(GcsConfig { endpoint, station })
            });
            out.extend(gcs);
        }
        out
    }
}

fn endpoint(
    g: &GcsSettings,
    autopilot: &Endpoint,
    owner: &str,
    used: &mut Unique<String>,
    ge: &mut ConfigErrors,
) -> Option<Endpoint> {
    let Some(text) = &g.endpoint else {
        ge.absent("endpoint", "is required, e.g. \"udpout:127.0.0.1:14550\"");
        return None;
    };
    let endpoint = match Endpoint::parse(text) {
        Ok(Endpoint::Serial { .. }) => Err("a ground station is on udpout:, udpin:, tcpin: or \
                                            tcpout: (a serial port is the autopilot's)"
            .to_string()),
        other => other,
    };
    let endpoint = endpoint
        .map_err(|rule| ge.add("endpoint", format!("\"{text}\""), rule))
        .ok()?;
    if endpoint == *autopilot {
        ge.add(
            "endpoint",
            format!("\"{text}\""),
            "is the autopilot's connection",
        );
        return None;
    }
    if let Some(first) = used.claim(endpoint.to_string(), owner) {
        let rule = format!("is {first}'s too");
        ge.add("endpoint", format!("\"{text}\""), rule);
        return None;
    }
    Some(endpoint)
}

fn station(
    g: &mut GcsSettings,
    endpoint: &Endpoint,
    own_system: Option<u8>,
    owner: &str,
    ids: &mut Unique<String>,
    ge: &mut ConfigErrors,
) -> Option<StationConfig> {
    let Some(id) = g.id else {
        for (key, set) in [
            ("system_id", g.system_id.is_some()),
            ("name", g.name.is_some()),
            ("level", g.level.is_some()),
            ("device_class", g.device_class.is_some()),
            ("security", g.security.is_some()),
        ] {
            if set {
                ge.add(
                    key,
                    "set",
                    "needs `id`: only a station with an id is an operator",
                );
            }
        }
        return None;
    };
    let id = ge.int::<i64>("id", id, 1..=i64::from(i32::MAX), "")?;
    if let Some(first) = ids.claim(id.to_string(), owner) {
        ge.add("id", id, format!("is {first}'s too"));
    }
    let Some(system_id) = g.system_id else {
        ge.absent(
            "system_id",
            "is required with `id`: the station's MAVLink system id",
        );
        return None;
    };
    let system_id = ge.int::<u8>("system_id", system_id, 1..=255, "")?;
    if Some(system_id) == own_system {
        let rule = "is rove's own system id: the autopilot could not tell the two apart";
        ge.add("system_id", system_id, rule);
    }
    let name = g.name.get_or_insert_with(|| "GCS".into()).clone();
    let level = *g.level.get_or_insert(Level::Stationary);
    let class = *g.device_class.get_or_insert(DeviceClass::Desktop);
    let feed = Arc::new(Feed::new(format!(
        "{name} ({id}, MAVLink system {system_id}) on {endpoint}"
    )));
    Some(StationConfig {
        id,
        system_id,
        name,
        level,
        class,
        security: g.security.clone(),
        feed,
    })
}
