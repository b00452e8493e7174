//! The seed's wire data model (docs/design.md §2), exactly: three topic types and their enums.
//!
//! Field order here *is* the wire order: serde serialises struct fields in declaration order and
//! the DDS binding puts these values on the wire with a plain-CDR (XCDR1) serde adapter, unchanged.
//! IDL enums travel as 4-byte values equal to their IDL values (`serde_repr`, `#[repr(u32)]`):
//! a plain serde enum would send the variant *index*, which breaks `Mode_t` (0/10/20).
//!
//! Deserialising an unknown enum value is an error, never a panic, so a malformed sample from the
//! network is rejected by the decoder before it reaches any state machine.
//!
//! IDL mapping: `long long` → `i64`, `long` → `i32`, `short` → `i16`, `string` → `String`,
//! `TimeBase::TimeT` → [`TimeT`] (`u64`).

use serde::{Deserialize, Serialize};
use serde_repr::{Deserialize_repr, Serialize_repr};
use std::time::Duration;

/// A device's identity on the DDS network (`long long device_id`).
pub type DeviceId = i64;

/// Full scale of a movement axis: axes are ±32767; −32768 is treated as −32767.
pub const AXIS_MAX: i16 = i16::MAX;

/// Wire type names: a foreign DDS matches topics on name *and* type name (docs/design.md §2).
pub mod type_names {
    /// Type name of [`super::DeviceInfo`].
    pub const DEVICE_INFO: &str = "RoVe::DeviceInfo";
    /// Type name of [`super::ControlCommand`].
    pub const CONTROL_COMMAND: &str = "RoVe::ControlCommand";
    /// Type name of [`super::RequestControl`].
    pub const REQUEST_CONTROL: &str = "RoVe::RequestControl";
    /// Type name of [`super::VehicleStatus`].
    pub const VEHICLE_STATUS: &str = "RoVe::VehicleStatus";
}

/// Topic names of the seed.
pub mod topic_names {
    /// Topic of [`super::DeviceInfo`], keyed by `device_id`.
    pub const DEVICE_INFO: &str = "DeviceInfo";
    /// Topic of [`super::ControlCommand`], keyed by `dest_id`.
    pub const CONTROL_COMMAND: &str = "ControlCommand";
    /// Topic of [`super::RequestControl`].
    pub const REQUEST_CONTROL: &str = "RequestControl";
    /// Topic of [`super::VehicleStatus`], keyed by `vehicle_id` (rove's own, beside the seed's).
    pub const VEHICLE_STATUS: &str = "VehicleStatus";
}

/// `enum Device_type_t { VEHICLE, CONTROLLER }`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize_repr, Deserialize_repr)]
#[repr(u32)]
pub enum DeviceType {
    /// A vehicle computer running `rove vehicle`.
    Vehicle = 0,
    /// An operator device running `rove operator`.
    Controller = 1,
}

/// `struct DeviceInfo`, topic `DeviceInfo`, key `device_id`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct DeviceInfo {
    /// The publishing device.
    pub device_id: DeviceId,
    /// Human-readable name.
    pub name: String,
    /// Vehicle or controller.
    pub device_type: DeviceType,
    /// Vehicles: the current owner's `device_id`; the vehicle's own id when its failsafe owns it.
    /// Controllers: by convention their own id.
    pub controller_id: DeviceId,
}

/// `enum Output_state_t { OUTPUT_OK, OUTPUT_DEGRADED, OUTPUT_DOWN, OUTPUT_HUNG }`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize_repr, Deserialize_repr)]
#[repr(u32)]
pub enum OutputState {
    /// Working.
    Ok = 0,
    /// Working with problems (retries, dropped frames).
    Degraded = 1,
    /// Not working: the outputs are held safe while it is retried.
    Down = 2,
    /// A device call has not returned: the outputs cannot change until it does.
    Hung = 3,
}

/// `struct VehicleStatus`, topic `VehicleStatus`, key `vehicle_id`: what a vehicle's outputs are
/// doing. rove's own topic beside the seed's three; a peer that knows only those ignores it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct VehicleStatus {
    /// The publishing vehicle.
    pub vehicle_id: DeviceId,
    /// Its owner, as in DeviceInfo (its own id when its failsafe owns it).
    pub controller_id: DeviceId,
    /// The mode last applied (MANUAL before any).
    pub mode: Mode,
    /// The outputs are in the safe state.
    pub failsafe: bool,
    /// The output's health.
    pub output: OutputState,
    /// The output's own words: its error, or an autopilot's mode and armed state.
    pub detail: String,
    /// The vehicle's health as its device reports it (battery, autopilot).
    pub health: VehicleHealth,
}

/// `struct VehicleHealth` (inside VehicleStatus): what the vehicle's device says of the vehicle,
/// for the people driving it. Each field has an "unknown" value, for outputs that cannot tell.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct VehicleHealth {
    /// Battery voltage, millivolts; `-1` unknown.
    pub battery_mv: i32,
    /// Battery remaining, percent (0–100); `-1` unknown.
    pub battery_pct: i16,
    /// The battery is at or below the vehicle's warning level (`[vehicle] battery_low_pct`).
    pub battery_low: bool,
    /// The autopilot's own mode name (`"HOLD"`, `"LOITER"`); empty: no autopilot, or not heard.
    pub autopilot_mode: String,
    /// The autopilot says it is armed.
    pub armed: bool,
    /// Time since the autopilot was last heard, ms; `-1`: no autopilot link, or never heard.
    pub link_age_ms: i32,
    /// The output holds the vehicle safe by its own decision while an operator owns it (an
    /// autopilot refused the operator's mode): `failsafe` is then set with the owner unchanged.
    pub held: bool,
}

impl VehicleHealth {
    /// Nothing known: what outputs without telemetry report.
    pub const UNKNOWN: VehicleHealth = VehicleHealth {
        battery_mv: -1,
        battery_pct: -1,
        battery_low: false,
        autopilot_mode: String::new(),
        armed: false,
        link_age_ms: -1,
        held: false,
    };
}

impl Default for VehicleHealth {
    fn default() -> Self {
        VehicleHealth::UNKNOWN
    }
}

/// `enum Command_type_t { PROBE, MOVEMENT, MODE }`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize_repr, Deserialize_repr)]
#[repr(u32)]
pub enum CommandType {
    /// Keep-alive only (the seed probed ownership with it); accepted for compatibility.
    Probe = 0,
    /// Drive: `movement_command` and `mode` apply.
    Movement = 1,
    /// Change mode only: `mode` applies, `movement_command` is ignored.
    Mode = 2,
}

/// `enum Mode_t { MANUAL = 0, ASSISTED = 10, AUTO = 20 }`.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize_repr, Deserialize_repr,
)]
#[repr(u32)]
pub enum Mode {
    /// Sticks drive the actuators (rover manual, multirotor Manual).
    Manual = 0,
    /// Stabilised (multirotor ATTI / autopilot assisted modes).
    Assisted = 10,
    /// The vehicle's own automation (GPS hold, Auto, Loiter…).
    Auto = 20,
}

impl Mode {
    /// All modes in wire order, for exhaustive tests and config tables.
    pub const ALL: [Mode; 3] = [Mode::Manual, Mode::Assisted, Mode::Auto];
}

/// `struct MovementCommand { short throttle; short roll; short pitch; short yaw; }`.
///
/// Axes are ±32767. For a UGV throttle is forward/back and steering is `roll`; for a multirotor
/// throttle −32767 is idle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
pub struct MovementCommand {
    /// Throttle axis.
    pub throttle: i16,
    /// Roll axis (UGV steering).
    pub roll: i16,
    /// Pitch axis.
    pub pitch: i16,
    /// Yaw axis.
    pub yaw: i16,
}

impl MovementCommand {
    /// All axes centred.
    pub const CENTRED: MovementCommand = MovementCommand {
        throttle: 0,
        roll: 0,
        pitch: 0,
        yaw: 0,
    };
}

/// `struct ControlCommand`, topic `ControlCommand`, key `dest_id`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ControlCommand {
    /// The sending controller's device id.
    pub src_id: DeviceId,
    /// The vehicle this command is for.
    pub dest_id: DeviceId,
    /// Probe (keep-alive), movement or mode.
    pub command_type: CommandType,
    /// Stick values (used when `command_type` is `Movement`).
    pub movement_command: MovementCommand,
    /// Requested mode (used for `Movement` and `Mode`).
    pub mode: Mode,
    /// Source time stamp. Informational: sender clocks are not synchronised with the vehicle's,
    /// so freshness is judged on the vehicle's own clock at arrival, never from this field.
    pub timestamp: TimeT,
}

/// `enum ack_t { REQUEST, ACCEPT, REFUSE, FINISH }`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize_repr, Deserialize_repr)]
#[repr(u32)]
pub enum Ack {
    /// The requester asks the current owner for the vehicle.
    Request = 0,
    /// The owner gives the vehicle to the requester (a priority grant).
    Accept = 1,
    /// The owner keeps the vehicle.
    Refuse = 2,
    /// The grant holder gives the vehicle back.
    Finish = 3,
}

/// `struct RequestControl`, topic `RequestControl`.
///
/// All messages of one handover carry the same triple: `src_id` = the requester, `dest_id` = the
/// vehicle, `current_controller_id` = the owner asked; `ack` gives the stage. Receivers act only on
/// samples where they are `current_controller_id`, `src_id` or (vehicles) `dest_id`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct RequestControl {
    /// The requester (the operator that wants, or holds, the grant).
    pub src_id: DeviceId,
    /// The vehicle.
    pub dest_id: DeviceId,
    /// The owner whose consent is asked.
    pub current_controller_id: DeviceId,
    /// The requester's priority, compared with the owner's strength by auto-accept.
    pub src_priority: i32,
    /// Stage of the handover.
    pub ack: Ack,
    /// Source time stamp (informational, see [`ControlCommand::timestamp`]).
    pub timestamp: TimeT,
}

impl RequestControl {
    /// The device that sends this stage of a handover, whose participant must be the sender:
    /// the requester for REQUEST and FINISH, the owner asked for ACCEPT and REFUSE.
    pub fn sender_id(&self) -> DeviceId {
        match self.ack {
            Ack::Request | Ack::Finish => self.src_id,
            Ack::Accept | Ack::Refuse => self.current_controller_id,
        }
    }
}

/// OMG `TimeBase::TimeT`: an unsigned count of 100 ns intervals since 1582-10-15 00:00 UTC
/// (the start of the Gregorian calendar).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default, Serialize, Deserialize,
)]
#[serde(transparent)]
pub struct TimeT(pub u64);

impl TimeT {
    /// 100 ns intervals between 1582-10-15 and the Unix epoch 1970-01-01
    /// (141 427 days × 86 400 s × 10⁷).
    pub const UNIX_EPOCH: TimeT = TimeT(122_192_928_000_000_000);

    /// Converts a time since the Unix epoch (as `SystemTime::duration_since(UNIX_EPOCH)` gives).
    /// Saturates at the end of the representable range.
    pub fn from_unix(since_epoch: Duration) -> TimeT {
        let ticks = u64::try_from(since_epoch.as_nanos() / 100).unwrap_or(u64::MAX);
        TimeT(Self::UNIX_EPOCH.0.saturating_add(ticks))
    }

    /// The time since the Unix epoch, or `None` for a time stamp before 1970.
    pub fn to_unix(self) -> Option<Duration> {
        let ticks = self.0.checked_sub(Self::UNIX_EPOCH.0)?;
        Some(Duration::from_nanos(ticks.saturating_mul(100)))
    }
}

#[cfg(test)]
mod tests {
    //! Golden-byte tests: the exact XCDR1 little-endian encoding of each seed type, field by field.
    //! `cdr` (dev-only) is an independent CDR implementation, so these check our serde shape against
    //! the CDR rules, not against ourselves.
    use super::*;
    use cdr::{CdrLe, Infinite};

    /// Serialises like a DDS plain-CDR LE payload, minus the 4-byte encapsulation header.
    fn cdr_body<T: Serialize>(value: &T) -> Vec<u8> {
        let bytes = cdr::serialize::<_, _, CdrLe>(value, Infinite).expect("serialisable");
        bytes[4..].to_vec()
    }

    fn decode<T: for<'de> Deserialize<'de>>(body: &[u8]) -> Result<T, cdr::Error> {
        let mut framed = vec![0x00, 0x01, 0x00, 0x00]; // CDR_LE encapsulation header
        framed.extend_from_slice(body);
        cdr::deserialize::<T>(&framed)
    }

    fn sample_command() -> ControlCommand {
        ControlCommand {
            src_id: 0x0102,
            dest_id: -2,
            command_type: CommandType::Mode,
            movement_command: MovementCommand {
                throttle: 1,
                roll: -1,
                pitch: 0x7fff,
                yaw: -32767,
            },
            mode: Mode::Assisted,
            timestamp: TimeT(0x1122_3344_5566_7788),
        }
    }

    #[test]
    fn control_command_is_40_bytes_in_field_order() {
        #[rustfmt::skip]
        let golden: [u8; 40] = [
            0x02, 0x01, 0, 0, 0, 0, 0, 0,                   // src_id = 0x0102
            0xfe, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, // dest_id = -2
            2, 0, 0, 0,                                     // command_type = MODE (4 bytes)
            1, 0,                                           // throttle = 1
            0xff, 0xff,                                     // roll = -1
            0xff, 0x7f,                                     // pitch = 32767
            0x01, 0x80,                                     // yaw = -32767
            10, 0, 0, 0,                                    // mode = ASSISTED (IDL value 10)
            0x88, 0x77, 0x66, 0x55, 0x44, 0x33, 0x22, 0x11, // timestamp (8-aligned at 32)
        ];
        assert_eq!(cdr_body(&sample_command()), golden);
        assert_eq!(
            decode::<ControlCommand>(&golden).ok(),
            Some(sample_command())
        );
    }

    #[test]
    fn enums_travel_as_their_idl_values() {
        for (mode, value) in [(Mode::Manual, 0u32), (Mode::Assisted, 10), (Mode::Auto, 20)] {
            assert_eq!(cdr_body(&mode), value.to_le_bytes());
        }
        for (ack, value) in [
            (Ack::Request, 0u32),
            (Ack::Accept, 1),
            (Ack::Refuse, 2),
            (Ack::Finish, 3),
        ] {
            assert_eq!(cdr_body(&ack), value.to_le_bytes());
        }
        assert_eq!(cdr_body(&DeviceType::Controller), 1u32.to_le_bytes());
        assert_eq!(cdr_body(&CommandType::Probe), 0u32.to_le_bytes());
    }

    #[test]
    fn device_info_encodes_string_with_length_and_nul() {
        let info = DeviceInfo {
            device_id: 7,
            name: "ab".into(),
            device_type: DeviceType::Vehicle,
            controller_id: 7,
        };
        #[rustfmt::skip]
        let golden: Vec<u8> = vec![
            7, 0, 0, 0, 0, 0, 0, 0,   // device_id
            3, 0, 0, 0, b'a', b'b', 0,// name: length incl. NUL, bytes, NUL
            0,                        // pad to 4 (offset 16)
            0, 0, 0, 0,               // device_type = VEHICLE
            0, 0, 0, 0,               // pad to 8
            7, 0, 0, 0, 0, 0, 0, 0,   // controller_id (8-aligned at 24)
        ];
        assert_eq!(cdr_body(&info), golden);
        assert_eq!(decode::<DeviceInfo>(&golden).ok(), Some(info));
    }

    #[test]
    fn request_control_layout() {
        let req = RequestControl {
            src_id: 1,
            dest_id: 2,
            current_controller_id: 3,
            src_priority: -4,
            ack: Ack::Finish,
            timestamp: TimeT(5),
        };
        #[rustfmt::skip]
        let golden: Vec<u8> = vec![
            1, 0, 0, 0, 0, 0, 0, 0,   // src_id
            2, 0, 0, 0, 0, 0, 0, 0,   // dest_id
            3, 0, 0, 0, 0, 0, 0, 0,   // current_controller_id
            0xfc, 0xff, 0xff, 0xff,   // src_priority = -4 (long = i32)
            3, 0, 0, 0,               // ack = FINISH
            5, 0, 0, 0, 0, 0, 0, 0,   // timestamp
        ];
        assert_eq!(cdr_body(&req), golden);
        assert_eq!(decode::<RequestControl>(&golden).ok(), Some(req));
    }

    #[test]
    fn unknown_enum_values_and_short_input_are_errors_not_panics() {
        let mut bytes = cdr_body(&sample_command());
        bytes[16] = 7; // command_type = 7: not an IDL value
        assert!(decode::<ControlCommand>(&bytes).is_err());
        let mut bytes = cdr_body(&sample_command());
        bytes[28] = 5; // mode = 5: between MANUAL and ASSISTED
        assert!(decode::<ControlCommand>(&bytes).is_err());
        let bytes = cdr_body(&sample_command());
        assert!(decode::<ControlCommand>(&bytes[..39]).is_err());
        assert!(decode::<ControlCommand>(&[]).is_err());
    }

    #[test]
    fn timet_counts_100ns_since_gregorian_reform() {
        assert_eq!(TimeT::from_unix(Duration::ZERO), TimeT::UNIX_EPOCH);
        // 2000-01-01T00:00:00Z = 946 684 800 s after the Unix epoch.
        let y2k = TimeT::from_unix(Duration::from_secs(946_684_800));
        assert_eq!(y2k.0, 122_192_928_000_000_000 + 9_466_848_000_000_000);
        assert_eq!(y2k.to_unix(), Some(Duration::from_secs(946_684_800)));
        assert_eq!(TimeT(0).to_unix(), None);
        assert_eq!(TimeT::from_unix(Duration::MAX), TimeT(u64::MAX));
        // Sub-100 ns precision is truncated, not rounded.
        assert_eq!(
            TimeT::from_unix(Duration::from_nanos(199)).0,
            TimeT::UNIX_EPOCH.0 + 1
        );
    }
}
