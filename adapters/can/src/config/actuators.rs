//! Validating `[output.dronecan]`: our node id, priority and rate, and its servos
//! (ArrayCommand) and ESC channels (RawCommand), each named and placed uniquely.

use super::validate::{check_rate, int_scale, period_of};
use super::{
    DEFAULT_PRIORITY, DroneCanConfig, DroneCanSettings, EscConfig, EscSettings, ServoConfig,
    ServoSettings, SourceSettings,
};
use crate::dronecan::{MAX_ESCS, MAX_SERVOS, NODE_ID_RANGE, PRIORITY_RANGE, RAW_COMMAND_RANGE};
use crate::scale::UnitScale;
use rove_core::config::{Int, Unique};
use rove_core::error::ConfigErrors;

impl DroneCanSettings {
    pub(super) fn validate(
        &mut self,
        section_rate: Int,
        names: &mut Unique<String>,
        errors: &mut ConfigErrors,
    ) -> Option<DroneCanConfig> {
        let node_id = errors.req_int("node_id", self.node_id, NODE_ID_RANGE, " (0 is anonymous)");
        let priority = *self.priority.get_or_insert(DEFAULT_PRIORITY);
        let priority = errors.int("priority", priority, PRIORITY_RANGE, " (0 highest)");
        let rate = check_rate(&mut self.rate_hz, section_rate, errors);
        if self.servos.is_empty() && self.escs.is_empty() {
            let rule = "[output.dronecan] needs at least one of [[output.dronecan.servos]] or \
                        [[output.dronecan.escs]]";
            errors.add("servos", "[]", rule);
        }
        if self.servos.len() > MAX_SERVOS {
            let rule = format!("at most {MAX_SERVOS} (one ArrayCommand)");
            errors.add("servos", format!("{} entries", self.servos.len()), rule);
        }
        let (servos, escs) = (&mut self.servos, &mut self.escs);
        let servo = |s: &ServoConfig| (s.name.clone(), "actuator_id", s.actuator_id);
        let servos = actuators(
            "servos",
            servos,
            ServoSettings::validate,
            servo,
            names,
            errors,
        );
        let esc = |e: &EscConfig| (e.name.clone(), "index", e.index);
        let escs = actuators("escs", escs, EscSettings::validate, esc, names, errors);
        Some(DroneCanConfig {
            node_id: node_id?,
            priority: priority?,
            period: period_of(rate),
            servos: servos?,
            escs: escs?,
        })
    }
}

/// Validates DroneCAN `servos` or `escs` (`list`) with `validate`: each named uniquely among
/// every output and at a `place` (its name, and the key and number of its actuator id or
/// index) of its own; `None` if any has a problem.
fn actuators<S, C>(
    list: &str,
    settings: &mut [S],
    validate: fn(&mut S, &str, &mut ConfigErrors) -> Option<C>,
    place: fn(&C) -> (String, &'static str, u8),
    names: &mut Unique<String>,
    errors: &mut ConfigErrors,
) -> Option<Vec<C>> {
    let (mut out, mut places, mut ok) = (Vec::new(), Unique::default(), true);
    for (i, s) in settings.iter_mut().enumerate() {
        let (mut se, owner) = (ConfigErrors::default(), format!("{list}[{i}]"));
        let actuator = validate(s, &format!("dronecan.{owner}"), &mut se);
        if let Some((name, key, number)) = actuator.as_ref().map(place) {
            let (name_key, shown) = (format!("{owner}.name"), format!("{name:?}"));
            let (first, what) = (format!("dronecan.{name_key}"), "has the same name");
            names.check(errors, name, first, (name_key.as_str(), shown), what);
            places.check(&mut se, number, &owner, (key, number), "has the same");
        }
        ok &= actuator.is_some() && se.0.is_empty();
        errors.extend_within(&owner, se);
        out.extend(actuator);
    }
    ok.then_some(out)
}

impl ServoSettings {
    fn validate(&mut self, default_name: &str, errors: &mut ConfigErrors) -> Option<ServoConfig> {
        (self.unknown).check(errors, Self::KNOWN);
        let name = (self.name.clone()).unwrap_or_else(|| default_name.into());
        let actuator_id = errors.req_int("actuator_id", self.actuator_id, 0..=255, "");
        let source = SourceSettings::validate(&self.source, errors);
        let range = (-1.0..=1.0, "must be -1..=1 (a unitless actuator command)");
        let mid = |a, b| (a + b) / 2.0;
        let checked = self.scale.check((-1.0, 1.0), mid, None, range, errors)?;
        let [min, centre, max, failsafe] = checked.map(|v| v as f32);
        Some(ServoConfig {
            name,
            actuator_id: actuator_id?,
            source: source?,
            scale: UnitScale { min, centre, max },
            failsafe,
        })
    }
}

impl EscSettings {
    fn validate(&mut self, default_name: &str, errors: &mut ConfigErrors) -> Option<EscConfig> {
        (self.unknown).check(errors, Self::KNOWN);
        let name = (self.name.clone()).unwrap_or_else(|| default_name.into());
        let unit = format!(" (RawCommand has {MAX_ESCS} channels)");
        let index = errors.req_int("index", self.index, 0..=(MAX_ESCS as Int - 1), &unit);
        let source = SourceSettings::validate(&self.source, errors);
        let range = (*RAW_COMMAND_RANGE.start(), *RAW_COMMAND_RANGE.end());
        let (scale, failsafe) = int_scale(&mut self.scale, (0, range.1), Some(0), range, errors)?;
        Some(EscConfig {
            name,
            index: index?,
            source: source?,
            scale,
            failsafe,
        })
    }
}
