//! `rove-core`: the pure control core of rove, the gateway that lets several operators share
//! control of several robots safely.
//!
//! It answers one question, correctly at every instant: *who drives this vehicle?* — and holds
//! everything the DDS binding, the adapters and the benchmarks share: the seed's wire data model,
//! the control hierarchy, the ownership arbiter, the active-handover state machines, the safety
//! timers, the axis → pulse mapping and the adapter traits.
//!
//! This crate must **not** do I/O, spawn threads, use async or read a clock. Time is an argument
//! ([`MonoTime`]); every state machine is stepped with `now` and an event, and returns what to
//! do. It depends on no DDS, tokio, MAVLink, evdev or hardware crate (`cargo tree -p rove-core
//! -e normal` shows serde, serde_repr and thiserror only).
//!
//! # Layout
//! - [`msg`]: the seed IDL types (DeviceInfo, ControlCommand, RequestControl), wire-exact.
//! - [`hierarchy`]: level × device class → ownership strength.
//! - [`arbiter`]: the per-vehicle ownership state machine (docs/design.md §4).
//! - [`handover`]: REQUEST / ACCEPT / REFUSE / FINISH for requester and replier.
//! - [`session`]: the operator's decisions (streaming, input liveness, commands, handover).
//! - [`remote`]: stale-input rules for a remote front end (the browser console).
//! - [`watchdog`]: the command timeout and liveness watchdog.
//! - [`mapping`]: axis → µs (min/centre/max, trim, reverse, deadband, expo, slew), mode levels.
//! - [`adapter`]: output-adapter and input-source traits.
//! - [`sim`]: a recording output and a scripted input.
//! - [`site`]: sites joined over a wide-area link: the bridges' key space and what another
//!   site may say.
//! - [`time`]: monotonic instants.
//! - [`sender`]: who sent a message (participant, writer), as the binding names them.
//! - [`trust`]: device ids pinned to participants, and the strengths a vehicle believes.
//! - [`freshness`]: whether a command sample queued up too long to drive with.
//! - [`world`]: sessions and an arbiter joined by direct delivery (demo, tests, fuzzing).
//! - [`error`]: configuration errors (naming their keys) and classified link errors.
//! - [`config`]: the shared config vocabulary: integer policy, range/required/unique checks,
//!   unknown keys of tables built from shared pieces, and [`config_types!`], the one-line-a-key
//!   way every crate writes its config structs and keyword enums.

#![deny(missing_docs)]

pub mod adapter;
pub mod arbiter;
pub mod audit;
pub mod config;
pub mod error;
pub mod freshness;
pub mod handover;
pub mod hierarchy;
pub mod mapping;
pub mod msg;
pub mod remote;
pub mod sender;
pub mod session;
pub mod sim;
pub mod site;
pub mod time;
pub mod trust;
pub mod watchdog;
pub mod world;

pub use error::{Error, Result};
pub use time::MonoTime;
