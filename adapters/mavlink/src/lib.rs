//! `rove-mavlink`: drives an ArduPilot or PX4 autopilot as a well-behaved ground station.
//!
//! Selected by `[output] adapter = "mavlink"`. The gateway hands it setpoints; it sends
//! RC_CHANNELS_OVERRIDE (ArduPilot) or MANUAL_CONTROL (PX4, ArduPilot) at once and again at
//! `rate_hz` (autopilots time an override out), a GCS HEARTBEAT at 1 Hz with our own ids (255/190
//! by default, ArduPilot's `MAV_GCS_SYSID`), mode changes with MAV_CMD_DO_SET_MODE confirmed from
//! COMMAND_ACK or HEARTBEAT, and on failsafe the release values (or neutral sticks) plus the
//! configured safe mode. It never arms.
//!
//! # Layout
//! - [`config`]: the `[output]` keys, validation, per-autopilot mode tables.
//! - [`encode`]: sticks → override pulses / MANUAL_CONTROL fields; release and ignore values (pure).
//! - [`frame`]: bytes → messages with immediate resynchronisation; messages → frame bytes (pure).
//! - [`mode`]: the mode-command machine with retries (pure, stepped with `now`).
//! - [`link`]: the transport (udpin/udpout/tcpout with TCP_NODELAY/serial), opened here, with its
//!   reader thread and reconnect.
//! - [`memory`]: what the link learned (the autopilot's address and ids), kept on disk so that
//!   `rove failsafe` addresses the autopilot at once.
//! - [`vehicle`]: [`MavlinkVehicle`], the [`rove_core::adapter::OutputAdapter`].
//! - `kind.rs`: [`Mavlink`], the adapter as the gateway offers it
//!   ([`rove_core::adapter::OutputKind`]).
//!
//! Measured against ArduPilot Rover SITL: the reader decodes the `ardupilotmega`
//! dialect and resynchronises at once on bytes that are not a message ([`frame`]), TCP links have
//! `TCP_NODELAY`, the keep-alive sends only when no command did within the period, and a refused
//! driven mode is reported (and, by default, stops the driving).
//!
//! # Known limitations (intentional, not bugs)
//! - A frame still arriving whose payload holds a whole valid MAVLink frame yields to that inner
//!   frame (no message an autopilot sends a GCS tunnels MAVLink).
//! - Mode changes are not enforced continuously: a pilot's mode switch wins until rove's wish
//!   changes.
//! - rove never arms the vehicle.
//!
//! How ArduPilot treats a GCS (release values, override expiry, GCS failsafe) is recorded in
//! docs/mavlink.md, "ArduPilot as a GCS sees it"; the project's pymavlink test autopilot
//! (`testkit/fake_autopilot.py`) behaves the same way.

#![deny(missing_docs)]

pub mod config;
pub mod control;
pub mod encode;
pub mod frame;
mod kind;
pub mod link;
pub mod memory;
pub mod mode;
pub mod station;
pub mod vehicle;

pub use config::{MavlinkConfig, MavlinkSettings};
pub use kind::Mavlink;
pub use vehicle::{MavlinkVehicle, failsafe};
