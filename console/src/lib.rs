//! `rove-console`: the operator console of `rove operator` — a view model of what the operator
//! knows, its terminal rendering, the key and button bindings, and the local API (NDJSON on a
//! Unix socket) through which other front ends see the same events and send the same commands.
//!
//! The operator role (gateway) emits [`Event`]s on a `tokio::sync::broadcast` channel and
//! takes [`CommandRequest`]s from one `mpsc` channel. The terminal console ([`run_terminal`])
//! and every API client ([`ApiSocket::serve`]) sit on those two channels: the console has no
//! private path into the operator.
//!
//! ```text
//! operator ── broadcast<Stamped> ──┬─▶ run_terminal ─ keys / buttons ─┐
//!    ▲                             └─▶ ApiSocket::serve ─ clients ─────┤
//!    └──────────────── mpsc<CommandRequest> (reply: oneshot) ◀─────────┘
//! ```
//!
//! # Layout
//! - [`model`]: [`ConsoleState`] and [`Event`]: pure, time injected, no I/O.
//! - [`mod@standing`]: where a vehicle stands for this operator ([`Standing`]), derived once and
//!   shown the same by every front end.
//! - [`command`]: [`Command`], the single interface for keys, buttons and API clients.
//! - [`keys`]: keys and joystick buttons → commands, with on-screen confirmation.
//! - [`view`]: drawing; the device table shared with `rove status --watch`.
//! - [`api`]: the NDJSON wire format: command parsing, replies, event lines.
//! - [`server`]: the event hub every front end joins, and the Unix-socket server.
//! - [`terminal`]: the interactive terminal loop.
//! - [`error`]: [`ApiError`], the one error type.
//!
//! `model`, `standing`, `keys`, `view` and `api` read no clock and do no I/O; only `server` and
//! `terminal` touch sockets, threads and the terminal. The crate does not talk DDS and knows
//! nothing of the operator's writers: what to do with a command is the operator's decision.

#![deny(missing_docs)]

pub mod api;
pub mod command;
pub mod error;
pub mod keys;
pub mod model;
pub mod server;
pub mod standing;
pub mod terminal;
pub mod view;

pub use api::{ApiReply, event_json, parse_command};
pub use command::{Command, CommandRequest, CommandResult, Source};
pub use error::{ApiError, Result};
pub use keys::{on_action, on_key};
pub use model::{ConsoleState, Event, Identity, Stamped};
pub use server::{ApiSocket, Hub, Joined};
pub use standing::{Standing, standing};
pub use terminal::run_terminal;
pub use view::{DeviceRow, device_table, render, render_status};
