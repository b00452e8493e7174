//! `rove-can`: CAN output for rove — servo sets, ESCs and motor controllers on a SocketCAN
//! interface, driven from the same setpoints as every other adapter. A vehicle is TOML only:
//! **raw frames** (any CAN id, each output a field at a byte offset with its width, byte order,
//! signedness and scaling) and/or **DroneCAN** actuator commands
//! (`uavcan.equipment.actuator.ArrayCommand`, `uavcan.equipment.esc.RawCommand`) with the
//! DroneCAN NodeStatus heartbeat.
//!
//! # Layout
//! - [`config`]: `[output]` as written ([`CanSettings`]) and validated ([`CanConfig`]).
//! - [`scale`]: pure; output sources (an axis or a mix of axes) and axis → device units.
//! - [`raw`]: pure; raw-frame field encoding and decoding.
//! - [`dronecan`]: pure; DroneCAN transport (CAN id, tail byte, multi-frame CRC) and messages.
//! - [`protocol`]: pure; a vehicle's frames and command values for one movement or failsafe.
//! - [`bus`]: the [`CanBus`] trait, frames, errno classification, the in-memory [`FakeBus`].
//! - `socket` (feature `socketcan`, default): [`SocketCanBus`], the Linux SocketCAN bus.
//! - [`vehicle`]: [`CanVehicle`], the [`rove_core::adapter::OutputAdapter`].
//! - [`error`]: the crate's error, [`FrameError`] (a frame that cannot be built).
//! - `kind.rs`: [`Can`], the adapter as the gateway offers it
//!   ([`rove_core::adapter::OutputKind`]).
//!
//! This crate does no arbitration and reads no clock: time comes in as `now`. It never depends
//! on the gateway. The pure modules do no I/O.
//!
//! # Config keys (`[output]`, `adapter = "can"`)
//!
//! | key | where | meaning |
//! |---|---|---|
//! | `interface` | section | SocketCAN interface: `can0`, `vcan0`, `slcan0` (required) |
//! | `fd` | section | open in CAN FD mode; frames up to 64 bytes (default false) |
//! | `rate_hz` | section | send rate of frames and commands, 1..=1000 Hz (default 50) |
//! | `id` | `[[frames]]` | CAN identifier (required; `0x201`) |
//! | `extended` | `[[frames]]` | 29-bit identifier (default false) |
//! | `length` | `[[frames]]` | data bytes: 0..=8, or 12/16/20/24/32/48/64 with `fd` (default: just enough) |
//! | `rate_hz` | `[[frames]]` | this frame's rate (default: the section's) |
//! | `name` | `[[frames.outputs]]`, servos, escs | for logs and status; unique (default: its key path) |
//! | `source` | outputs, servos, escs | `"throttle"`, `"roll"`, `"pitch"`, `"yaw"` or `{ mix = [["throttle", 1.0], ["roll", -1.0]] }` (required) |
//! | `offset` | `[[frames.outputs]]` | first byte (required) |
//! | `width` | `[[frames.outputs]]` | 8, 16 or 32 bits (default 16) |
//! | `endian` | `[[frames.outputs]]` | `"little"` or `"big"` (default little) |
//! | `signed` | `[[frames.outputs]]` | two's complement (default true) |
//! | `min`, `centre`, `max` | outputs, servos, escs | device value at −full, centre, +full scale; `min > max` reverses |
//! | `failsafe` | outputs, servos, escs | safe-state value (default: centre; ESCs: 0) |
//! | `node_id` | `[dronecan]` | our node id 1..=127 (required) |
//! | `priority` | `[dronecan]` | command priority 0..=31 (default 16) |
//! | `rate_hz` | `[dronecan]` | command rate (default: the section's) |
//! | `actuator_id` | `[[dronecan.servos]]` | ArrayCommand actuator id 0..=255; values −1..=1, unitless |
//! | `index` | `[[dronecan.escs]]` | RawCommand index 0..=19; values −8192..=8191 (default min 0, max 8191) |
//!
//! Raw output defaults: `min`/`max` the field's range (symmetric for signed: ±32767 for 16
//! bits), `centre` halfway. A skid-steer rover mixes: `left = throttle + roll`,
//! `right = throttle − roll`, each clamped to full scale before scaling.
//!
//! # Behaviour
//! - Each frame and command goes out when its value changes and at least at its rate, in the
//!   safe state too: CAN devices time out a held command. [`CanVehicle`]'s keep-alive period
//!   is the shortest rate's period; the gateway must call `keepalive` at that period whether it
//!   is driving or not.
//! - Safe state: each output's `failsafe` value, sent at construction, on `safe_state`, and on
//!   drop.
//! - Bus-off, interface down or gone, full transmit queue: the call returns a transient
//!   [`rove_core::error::LinkError`], health goes Down, outputs fall back to the safe state. The
//!   vehicle retries every [`vehicle::REOPEN_INTERVAL`] (waiting for the controller's restart
//!   after bus-off, reopening the interface by name after a failed send) and sends the safe
//!   state once back, until the next `apply`. No restart of the gateway is needed.
//! - DroneCAN: NodeStatus at 1 Hz (health OK while driving, WARNING in the safe state); transfer
//!   ids counted per message type.
//!
//! # Known limitations (intentional, not bugs)
//! - DroneCAN goes on classic frames only (also on an FD interface), and only the unitless
//!   ArrayCommand command type is sent. Up to 15 servos and 20 ESC channels (one message each).
//! - No DroneCAN dynamic node id allocation: `node_id` is static and must be unique on the bus.
//!   rove does not answer `GetNodeInfo` requests (it never reads the bus).
//! - The bitrate is the interface's (`ip link set can0 type can bitrate 500000`); rove does not
//!   configure interfaces, which needs CAP_NET_ADMIN.
//! - Frames are sent when due *and* when their value changes, so the rate on the bus can reach
//!   the command rate (the operator's stream) plus the keep-alive rate.
//! - errno values are the asm-generic ones (x86, ARM, AArch64, RISC-V); see [`bus::errno`].
//! - Only tested against the in-memory bus on machines without CAN; `tests/vcan.rs` runs a real
//!   socket round trip where the kernel has vcan.

#![deny(missing_docs)]

pub mod bus;
pub mod config;
pub mod dronecan;
pub mod error;
mod kind;
pub mod protocol;
pub mod raw;
pub mod scale;
#[cfg(feature = "socketcan")]
pub mod socket;
pub mod vehicle;

pub use bus::{
    BusState, CanBus, CanFrameData, CanId, FakeBus, FakeBusHandle, FakeFault, SentFrame,
};
pub use config::{CanConfig, CanSettings};
pub use error::FrameError;
pub use kind::Can;
#[cfg(feature = "socketcan")]
pub use socket::SocketCanBus;
pub use vehicle::CanVehicle;

use rove_core::error::LinkError;

/// Opens the SocketCAN interface `config` names (in CAN FD mode if `fd = true`).
///
/// # Errors
/// A classified [`LinkError`]: transient while the interface does not exist or is down (the
/// gateway retries), fatal when the kernel has no SocketCAN or the build has no `socketcan`
/// feature.
pub fn open_bus(config: &CanConfig) -> Result<Box<dyn CanBus + Send>, LinkError> {
    #[cfg(feature = "socketcan")]
    {
        Ok(Box::new(SocketCanBus::open(&config.interface, config.fd)?))
    }
    #[cfg(not(feature = "socketcan"))]
    {
        Err(LinkError::fatal(format!(
            "{}: this rove was built without the `socketcan` feature of rove-can",
            config.interface
        )))
    }
}
