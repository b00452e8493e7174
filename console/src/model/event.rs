//! What the operator role reports to the console and to API clients: [`Event`], and
//! [`Stamped`], an event with the time it happened.

use super::{DeviceKind, Identity, InputStatus, Outcome};
use rove_core::MonoTime;
use rove_core::handover::Prompt;
use rove_core::msg::{DeviceId, Mode, OutputState, VehicleHealth};

/// Something the operator role reports to the console and to API clients.
///
/// Each maps to one thing `rove operator` already knows: a DeviceInfo sample or disposal, a
/// change of its own streams, a handover [`rove_core::handover::Action`], an input event.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Event {
    /// Who we are (send once at start).
    Identity(Identity),
    /// A DeviceInfo sample: the device is present; for a vehicle, `owner` is its
    /// `controller_id` (the vehicle's own id when its failsafe owns it).
    DeviceSeen {
        /// Device id.
        id: DeviceId,
        /// Name.
        name: String,
        /// Vehicle or controller.
        kind: DeviceKind,
        /// `controller_id` of the sample.
        owner: DeviceId,
    },
    /// The device withdrew (its DeviceInfo was disposed): shown offline.
    DeviceGone {
        /// Device id.
        id: DeviceId,
    },
    /// What a vehicle reports beyond its owner (from a status topic, when there is one).
    VehicleStatus {
        /// The vehicle.
        vehicle: DeviceId,
        /// The owner this status was published under (VehicleStatus's `controller_id`).
        owner: DeviceId,
        /// Its current mode, if known.
        mode: Option<Mode>,
        /// Its outputs are in the safe state.
        failsafe: bool,
        /// Output-link health, e.g. `"ok"` or `"down: /dev/ttyACM0 gone"`.
        link: String,
        /// The output's state.
        output: OutputState,
        /// What its device says of the vehicle (battery, autopilot).
        health: VehicleHealth,
    },
    /// The owner of a vehicle changed, with the reason the operator knows.
    OwnerChanged {
        /// The vehicle.
        vehicle: DeviceId,
        /// Previous owner (the vehicle's id = failsafe).
        from: DeviceId,
        /// New owner.
        to: DeviceId,
        /// Why, e.g. `"grant accepted"`, `"released"`, `"reported by the vehicle"`.
        reason: String,
    },
    /// What this operator streams to now (a full snapshot; vehicles not listed: nothing).
    Driving {
        /// Driven with the regular writer.
        driving: Vec<DeviceId>,
        /// Driven with the priority writer (grants held).
        holding: Vec<DeviceId>,
        /// Yielded to a grant holder.
        standby: Vec<DeviceId>,
        /// Waiting for live input.
        paused: Vec<DeviceId>,
    },
    /// Someone asks us for a vehicle we own ([`rove_core::handover::Action::AskOperator`]).
    RequestIncoming(Prompt),
    /// The consent prompt for `vehicle` closed ([`rove_core::handover::Action::PromptClosed`]).
    PromptClosed {
        /// The vehicle.
        vehicle: DeviceId,
        /// How.
        outcome: Outcome,
    },
    /// We asked `owner` for `vehicle` (a REQUEST went out).
    RequestSent {
        /// The vehicle.
        vehicle: DeviceId,
        /// The owner asked.
        owner: DeviceId,
    },
    /// Our own request ended ([`rove_core::handover::Action::RequestEnded`]).
    RequestEnded {
        /// The vehicle.
        vehicle: DeviceId,
        /// How.
        outcome: Outcome,
    },
    /// The input's state changed (sticks, mode, deadman, link).
    Input(InputStatus),
    /// The vehicle that buttons and keys act on.
    Selected {
        /// `None`: nothing selected.
        vehicle: Option<DeviceId>,
    },
    /// A line for the log (a refused command, a warning).
    Notice {
        /// The text.
        text: String,
    },
    /// Time passed: devices go offline, prompts count down. Not sent to API clients.
    Tick,
}

/// An event with the time it happened: what the operator broadcasts.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Stamped {
    /// When (the operator's monotonic clock).
    pub at: MonoTime,
    /// What.
    pub event: Event,
}
