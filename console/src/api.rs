//! The local API's wire format: newline-delimited JSON (docs/api.md).
//!
//! Client → operator: one command object per line, e.g. `{"cmd":"drive","vehicle":100}`.
//! Operator → client: one object per line, either an event (`{"event":"owner",…}`) or the reply
//! to a command (`{"ok":true}` or `{"error":"…","code":"…","line":3}`), replies in command
//! order. Parsing never panics: every malformed line is an [`ApiError`] value.

use crate::command::Command;
use crate::error::{ApiError, Result};
use crate::model::{Event, Stamped};
use crate::standing::Standing;
use crate::view::{autopilot_text, battery_text, mode_name};
use rove_core::MonoTime;
use rove_core::handover::Prompt;
use rove_core::msg::{DeviceId, Mode, VehicleHealth};
use serde_json::{Map, Value, json};

/// Protocol version, sent in the `hello` event. Bumped when a field changes meaning or goes
/// away; new fields and new events do not bump it (clients ignore what they do not know).
pub const PROTOCOL_VERSION: u32 = 1;

/// Longest accepted line, in bytes (64 KiB): a command is under 100 bytes, so anything near
/// this is not a command; the bound keeps a broken client from growing the operator's memory.
pub const MAX_LINE_BYTES: usize = 64 * 1024;

/// Parses one command line (without its newline).
///
/// # Errors
/// Every way a line can be wrong, as an [`ApiError`] line error: too long, not UTF-8, bad JSON,
/// not an object, no `cmd`, unknown `cmd`, a missing, invalid or unknown field.
pub fn parse_command(line: &str) -> Result<Command> {
    if line.len() > MAX_LINE_BYTES {
        return Err(ApiError::TooLong {
            max: MAX_LINE_BYTES,
        });
    }
    let value: Value = serde_json::from_str(line).map_err(|e| ApiError::BadJson(e.to_string()))?;
    let Value::Object(obj) = value else {
        return Err(ApiError::NotAnObject);
    };
    let Some(Value::String(name)) = obj.get("cmd") else {
        return Err(ApiError::MissingCmd);
    };
    let fields = Fields { obj: &obj };
    let command = match name.as_str() {
        "select" => Command::Select {
            vehicle: fields.vehicle("select")?,
        },
        "drive" => Command::Drive {
            vehicle: fields.vehicle("drive")?,
        },
        "release" => Command::Release {
            vehicle: fields.optional_vehicle("release")?,
        },
        "request" => Command::Request {
            vehicle: fields.vehicle("request")?,
        },
        "accept" => Command::Accept {
            vehicle: fields.vehicle("accept")?,
        },
        "refuse" => Command::Refuse {
            vehicle: fields.vehicle("refuse")?,
        },
        "finish" => Command::Finish {
            vehicle: fields.vehicle("finish")?,
        },
        "mode" => Command::Mode {
            vehicle: fields.optional_vehicle("mode")?,
            mode: fields.mode("mode")?,
        },
        other => return Err(ApiError::UnknownCmd(other.chars().take(64).collect())),
    };
    let allowed: &[&str] = match command {
        Command::Mode { .. } => &["cmd", "vehicle", "mode"],
        _ => &["cmd", "vehicle"],
    };
    if let Some(extra) = obj.keys().find(|k| !allowed.contains(&k.as_str())) {
        return Err(ApiError::UnknownField {
            cmd: command.name(),
            field: extra.chars().take(64).collect(),
        });
    }
    Ok(command)
}

/// Parses a raw line as read from the socket (bytes, maybe not UTF-8).
///
/// # Errors
/// As [`parse_command`], plus [`ApiError::NotUtf8`].
pub fn parse_command_bytes(line: &[u8]) -> Result<Command> {
    if line.len() > MAX_LINE_BYTES {
        return Err(ApiError::TooLong {
            max: MAX_LINE_BYTES,
        });
    }
    let text = std::str::from_utf8(line).map_err(|_| ApiError::NotUtf8)?;
    parse_command(text)
}

struct Fields<'a> {
    obj: &'a Map<String, Value>,
}

impl Fields<'_> {
    fn vehicle(&self, cmd: &'static str) -> Result<DeviceId> {
        self.optional_vehicle(cmd)?.ok_or(ApiError::MissingField {
            cmd,
            field: "vehicle",
        })
    }

    /// A device id: a JSON integer, or a decimal string (JavaScript numbers lose precision
    /// above 2^53, so clients may send ids as strings).
    fn optional_vehicle(&self, cmd: &'static str) -> Result<Option<DeviceId>> {
        let invalid = |why: &str| ApiError::InvalidField {
            cmd,
            field: "vehicle",
            why: why.into(),
        };
        match self.obj.get("vehicle") {
            None | Some(Value::Null) => Ok(None),
            Some(Value::Number(n)) => n
                .as_i64()
                .map(Some)
                .ok_or_else(|| invalid("expected a device id (an integer within i64)")),
            Some(Value::String(s)) => s
                .parse::<DeviceId>()
                .map(Some)
                .map_err(|_| invalid("expected a device id (an integer, or a string of one)")),
            Some(_) => Err(invalid("expected a device id (an integer)")),
        }
    }

    fn mode(&self, cmd: &'static str) -> Result<Mode> {
        match self.obj.get("mode") {
            None => Err(ApiError::MissingField { cmd, field: "mode" }),
            Some(Value::String(s)) => match s.as_str() {
                "manual" => Ok(Mode::Manual),
                "assisted" => Ok(Mode::Assisted),
                "auto" => Ok(Mode::Auto),
                _ => Err(ApiError::InvalidField {
                    cmd,
                    field: "mode",
                    why: "expected \"manual\", \"assisted\" or \"auto\"".into(),
                }),
            },
            Some(_) => Err(ApiError::InvalidField {
                cmd,
                field: "mode",
                why: "expected a string".into(),
            }),
        }
    }
}

/// A reply line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ApiReply {
    /// The command was carried out: `{"ok":true}`.
    Ok,
    /// It was not: `{"error":"…","code":"…","line":N}`.
    Error {
        /// What went wrong, for people.
        error: String,
        /// For programs: the [`ApiError::code`], or `"refused"` when the operator refused a
        /// well-formed command, `"unavailable"` when the operator is gone.
        code: &'static str,
        /// The client's line number (1-based) the reply is for.
        line: Option<u64>,
    },
}

impl ApiReply {
    /// The reply for a line that did not parse.
    pub fn parse_error(error: &ApiError, line: u64) -> ApiReply {
        ApiReply::Error {
            error: error.to_string(),
            code: error.code(),
            line: Some(line),
        }
    }

    /// The JSON line, without newline.
    pub fn to_json(&self) -> String {
        match self {
            ApiReply::Ok => json!({ "ok": true }).to_string(),
            ApiReply::Error { error, code, line } => {
                let mut obj = json!({ "error": error, "code": code });
                if let (Some(line), Some(map)) = (line, obj.as_object_mut()) {
                    map.insert("line".into(), json!(line));
                }
                obj.to_string()
            }
        }
    }
}

/// The command as a JSON line (what a client sends), e.g. for tests and client libraries.
pub fn command_json(command: &Command) -> String {
    let mut obj = json!({ "cmd": command.name() });
    let vehicle = match *command {
        Command::Select { vehicle }
        | Command::Drive { vehicle }
        | Command::Request { vehicle }
        | Command::Accept { vehicle }
        | Command::Refuse { vehicle }
        | Command::Finish { vehicle } => Some(vehicle),
        Command::Release { vehicle } | Command::Mode { vehicle, .. } => vehicle,
    };
    if let Some(map) = obj.as_object_mut() {
        if let Some(v) = vehicle {
            map.insert("vehicle".into(), json!(v));
        }
        if let Command::Mode { mode, .. } = command {
            map.insert("mode".into(), json!(mode_name(*mode)));
        }
    }
    obj.to_string()
}

fn millis(t: MonoTime) -> u64 {
    t.as_nanos() / 1_000_000
}

/// The `hello` line a client gets on connecting, before the snapshot.
pub fn hello_json(at: MonoTime, offline_after_ms: u64) -> String {
    json!({
        "event": "hello",
        "t_ms": millis(at),
        "version": PROTOCOL_VERSION,
        "offline_after_ms": offline_after_ms,
    })
    .to_string()
}

/// The `lagged` line: the client was too slow and `missed` events were dropped for it.
pub fn lagged_json(missed: u64) -> String {
    json!({ "event": "lagged", "missed": missed }).to_string()
}

/// A vehicle's health as the API gives it: the raw values (`null` where unknown) and the
/// consoles' words for them (`battery`, `autopilot`: `null` where there is nothing to show).
pub fn health_json(h: &VehicleHealth) -> Value {
    let known = |v: i64| (v >= 0).then_some(v);
    json!({
        "battery_mv": known(i64::from(h.battery_mv)),
        "battery_pct": known(i64::from(h.battery_pct)),
        "battery_low": h.battery_low,
        "autopilot_mode": (!h.autopilot_mode.is_empty()).then_some(&h.autopilot_mode),
        "armed": (!h.autopilot_mode.is_empty()).then_some(h.armed),
        "link_age_ms": known(i64::from(h.link_age_ms)),
        "held": h.held,
        "battery": battery_text(h),
        "autopilot": autopilot_text(h),
    })
}

/// The `standing` line: where `vehicle` stands for this operator (docs/api.md), in the words
/// every console uses.
pub fn standing_json(at: MonoTime, vehicle: DeviceId, standing: &Standing, text: &str) -> String {
    json!({
        "event": "standing", "vehicle": vehicle, "state": standing.kind(),
        "other": standing.other(), "safe": standing.is_safe(), "text": text,
        "t_ms": millis(at),
    })
    .to_string()
}

/// An event as a JSON line (no newline); `None` for [`Event::Tick`], which clients do not get.
pub fn event_json(stamped: &Stamped) -> Option<String> {
    let t_ms = millis(stamped.at);
    let value = match &stamped.event {
        Event::Identity(id) => json!({
            "event": "identity", "id": id.id, "name": id.name,
            "level": format!("{:?}", id.level).to_lowercase(),
            "class": format!("{:?}", id.class).to_lowercase(),
            "strength": id.strength.0,
        }),
        Event::DeviceSeen {
            id,
            name,
            kind,
            owner,
        } => json!({
            "event": "device", "id": id, "name": name, "kind": kind.as_str(), "owner": owner,
        }),
        Event::DeviceGone { id } => json!({ "event": "device_gone", "id": id }),
        Event::VehicleStatus {
            vehicle,
            owner: _,
            mode,
            failsafe,
            link,
            output: _,
            health,
        } => json!({
            "event": "vehicle_status", "vehicle": vehicle,
            "mode": mode.map(mode_name), "failsafe": failsafe, "link": link,
            "health": health_json(health),
        }),
        Event::OwnerChanged {
            vehicle,
            from,
            to,
            reason,
        } => json!({
            "event": "owner", "vehicle": vehicle, "from": from, "to": to, "reason": reason,
        }),
        Event::Driving {
            driving,
            holding,
            standby,
            paused,
        } => json!({
            "event": "driving", "driving": driving, "holding": holding,
            "standby": standby, "paused": paused,
        }),
        Event::RequestIncoming(Prompt {
            vehicle,
            requester: from,
            src_priority,
            deadline,
        }) => json!({
            "event": "request_incoming", "vehicle": vehicle, "from": from,
            "src_priority": src_priority, "deadline_ms": millis(*deadline),
            "timeout_ms": millis(*deadline).saturating_sub(t_ms),
        }),
        Event::PromptClosed { vehicle, outcome } => json!({
            "event": "prompt_closed", "vehicle": vehicle, "outcome": outcome.as_str(),
        }),
        Event::RequestSent { vehicle, owner } => json!({
            "event": "request_sent", "vehicle": vehicle, "owner": owner,
        }),
        Event::RequestEnded { vehicle, outcome } => json!({
            "event": "request_ended", "vehicle": vehicle, "outcome": outcome.as_str(),
        }),
        Event::Input(i) => json!({
            "event": "input",
            "throttle": i.movement.throttle, "roll": i.movement.roll,
            "pitch": i.movement.pitch, "yaw": i.movement.yaw,
            "mode": mode_name(i.mode), "deadman": i.deadman, "live": i.live, "link": i.link,
        }),
        Event::Selected { vehicle } => json!({ "event": "selected", "vehicle": vehicle }),
        Event::Notice { text } => json!({ "event": "notice", "text": text }),
        Event::Tick => return None,
    };
    let mut value = value;
    if let Some(map) = value.as_object_mut() {
        map.insert("t_ms".into(), json!(t_ms));
    }
    Some(value.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Outcome;

    #[test]
    fn parses_every_command() {
        let cases = [
            (
                r#"{"cmd":"select","vehicle":100}"#,
                Command::Select { vehicle: 100 },
            ),
            (
                r#"{"cmd":"drive","vehicle":100}"#,
                Command::Drive { vehicle: 100 },
            ),
            (r#"{"cmd":"release"}"#, Command::Release { vehicle: None }),
            (
                r#"{"cmd":"release","vehicle":"9007199254740993"}"#,
                Command::Release {
                    vehicle: Some(9_007_199_254_740_993),
                },
            ),
            (
                r#"{"cmd":"request","vehicle":-5}"#,
                Command::Request { vehicle: -5 },
            ),
            (
                r#" {"vehicle":1,"cmd":"accept"} "#,
                Command::Accept { vehicle: 1 },
            ),
            (
                r#"{"cmd":"refuse","vehicle":1}"#,
                Command::Refuse { vehicle: 1 },
            ),
            (
                r#"{"cmd":"finish","vehicle":1}"#,
                Command::Finish { vehicle: 1 },
            ),
            (
                r#"{"cmd":"mode","mode":"auto"}"#,
                Command::Mode {
                    vehicle: None,
                    mode: Mode::Auto,
                },
            ),
            (
                r#"{"cmd":"mode","mode":"assisted","vehicle":100}"#,
                Command::Mode {
                    vehicle: Some(100),
                    mode: Mode::Assisted,
                },
            ),
        ];
        for (line, want) in cases {
            assert_eq!(parse_command(line).ok(), Some(want), "{line}");
            assert_eq!(parse_command(&command_json(&want)).ok(), Some(want));
        }
    }

    #[test]
    fn every_kind_of_bad_line_is_an_error_value() {
        let long = format!(
            r#"{{"cmd":"drive","vehicle":1,"pad":"{}"}}"#,
            "x".repeat(MAX_LINE_BYTES)
        );
        let cases: [(&str, &str); 14] = [
            ("", "bad_json"),
            ("{", "bad_json"),
            ("drive 100", "bad_json"),
            ("[1,2]", "not_object"),
            ("42", "not_object"),
            (r#"{"vehicle":100}"#, "missing_cmd"),
            (r#"{"cmd":7}"#, "missing_cmd"),
            (r#"{"cmd":"fly","vehicle":1}"#, "unknown_cmd"),
            (r#"{"cmd":"drive"}"#, "missing_field"),
            (r#"{"cmd":"drive","vehicle":1.5}"#, "invalid_field"),
            (r#"{"cmd":"drive","vehicle":"rover"}"#, "invalid_field"),
            (r#"{"cmd":"mode","mode":"turbo"}"#, "invalid_field"),
            (
                r#"{"cmd":"drive","vehicle":1,"vehicel":2}"#,
                "unknown_field",
            ),
            (long.as_str(), "too_long"),
        ];
        for (line, code) in cases {
            match parse_command(line) {
                Err(e) => assert_eq!(e.code(), code, "{line:.80}: {e}"),
                Ok(c) => panic!("{line:.80} parsed as {c:?}"),
            }
        }
        assert_eq!(
            parse_command(r#"{"cmd":"mode"}"#).map_err(|e| e.to_string()),
            Err("mode: missing field \"mode\"".into())
        );
        assert_eq!(
            parse_command_bytes(b"{\"cmd\":\"drive\xff\"}").map_err(|e| e.code()),
            Err("not_utf8")
        );
        assert_eq!(
            parse_command(r#"{"cmd":"drive","vehicle":99999999999999999999}"#)
                .map_err(|e| e.code()),
            Err("invalid_field")
        );
    }

    #[test]
    fn replies_are_one_json_object() {
        assert_eq!(ApiReply::Ok.to_json(), r#"{"ok":true}"#);
        let e = ApiReply::parse_error(&ApiError::MissingCmd, 3);
        let v: Value = serde_json::from_str(&e.to_json()).unwrap_or_default();
        assert_eq!(v["error"], "missing \"cmd\" (a string)");
        assert_eq!(v["code"], "missing_cmd");
        assert_eq!(v["line"], 3);
    }

    #[test]
    fn events_serialise_with_time_and_name() {
        let at = MonoTime::from_millis(1_500);
        let line = event_json(&Stamped {
            at,
            event: Event::RequestIncoming(Prompt {
                vehicle: 100,
                requester: 7,
                src_priority: 340,
                deadline: MonoTime::from_millis(11_500),
            }),
        });
        let v: Value = serde_json::from_str(line.as_deref().unwrap_or("")).unwrap_or_default();
        assert_eq!(v["event"], "request_incoming");
        assert_eq!(v["t_ms"], 1_500);
        assert_eq!(v["deadline_ms"], 11_500);
        assert_eq!(v["timeout_ms"], 10_000);
        let line = event_json(&Stamped {
            at,
            event: Event::PromptClosed {
                vehicle: 100,
                outcome: Outcome::TimedOut,
            },
        });
        assert!(line.is_some_and(|l| l.contains(r#""outcome":"timed_out""#)));
        assert_eq!(
            event_json(&Stamped {
                at,
                event: Event::Tick
            }),
            None
        );
    }
}
