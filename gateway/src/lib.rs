//! `rove-gateway`: the process side of rove — the DDS binding, the vehicle and operator roles,
//! configuration, `rove status`, the demo, the handover benchmark and the process harness they
//! and the multi-process tests share. The binary `rove` (`main.rs`) is only the CLI on top.
//!
//! # Layout
//! - [`config`]: TOML files → validated configs; errors name file, line and key.
//! - [`dds`]: the seed topics on rustdds; GUID → core identities; strength from discovery.
//! - [`dds_log`]: rustdds's log records, rate-limited per call site.
//! - [`vehicle`], [`operator`]: the two roles, each one `select!` loop with injected edges
//!   (clock, shutdown, front ends); [`host`] assembles them on this machine for `main.rs`.
//! - [`output`]: the output adapter on its own thread behind the gateway's failure policy
//!   (hold, reopen, hung-device watch); `rove failsafe`.
//! - `bridge` (with the `remote` feature): `rove bridge`, a site's link to other sites over
//!   Zenoh, each remote device a participant of its own here.
//! - [`web`]: the browser operator console (`[web]`): pairing, HTTPS, WebSocket, the page.
//! - [`status`]: device list and ownership, table / JSON / event stream.
//! - [`audit`]: each vehicle's hash-chained log of who drove it, `rove audit`.
//! - [`doctor`]: `rove doctor`, what a board offers and what a config needs.
//! - `certs` (with the `security` feature): `rove keys`, a fleet's DDS Security files (CA,
//!   governance, each device's certificate and permissions); `keys` in the console is the keyboard.
//! - [`runtime`]: clock, signals, rate-limited warnings, logging.
//! - [`sdnotify`]: systemd readiness, status, watchdog keep-alives and stopping.

#![deny(missing_docs)]

pub mod audit;
#[cfg(feature = "remote")]
pub mod bridge;
#[cfg(feature = "security")]
pub mod certs;
pub mod config;
pub mod dds;
pub mod dds_log;
pub mod dirs;
pub mod doctor;
pub mod host;
pub mod operator;
pub mod output;
pub mod runtime;
pub mod sdnotify;
pub mod status;
pub mod vehicle;
pub mod web;
