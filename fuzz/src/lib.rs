//! rove's fuzz targets as plain functions, so that one body serves two engines: libFuzzer
//! (nightly, the cargo-fuzz project in `fuzz/libfuzzer/`) explores with it, and the stable
//! test `tests/corpora.rs` replays every committed corpus file through it in
//! `cargo test --workspace`. How to run a target, and what the runs found: `fuzz/README.md`.
//!
//! Every function takes any bytes and either returns or panics; a panic is a finding. Beyond
//! "no panic", each checks the invariants that are cheap to state (named in its docs).
//!
//! # Layout
//! - [`cdr`]: the DDS topics' CDR decoding, as a rove reader decodes a sample.
//! - [`arbiter`]: structure-aware event sequences against the vehicle's arbiter.
//! - [`session`]: operator sessions (and their handover machines) and an arbiter over a
//!   lossy network, with forged messages.
//! - [`config`]: config text of every kind through the gateway's loader.
//! - [`mavlink`]: bytes from an autopilot into rove-mavlink's frame decoder.
//! - [`dronecan`]: DroneCAN transfers split into frames and reassembled.
//! - [`replay`]: evdev recordings (text and raw `input_event` records) into rove-inputs.
//! - [`console_api`]: lines into the console API's command parser.
//! - [`rtps`]: RTPS datagrams into a participant with a vehicle's endpoints, through
//!   rustdds's receive path (message receiver, proxies, discovery).
//! - [`web_page`]: a browser's messages into the web console's parser and stale-input rules.
//! - [`site`]: another site's messages (key and payload) into the bridge's reader.
//! - `bytes`: the cursor the structure-aware targets draw their choices from.
//!
//! Not here: I/O. Targets never open files, sockets or devices.

#![deny(missing_docs)]

mod bytes;

pub mod arbiter;
pub mod cdr;
pub mod config;
pub mod console_api;
pub mod dronecan;
pub mod mavlink;
pub mod replay;
pub mod rtps;
pub mod session;
pub mod site;
pub mod web_page;

/// A target's body: any bytes in; a panic is a finding.
pub type Target = fn(&[u8]);

/// The fuzz targets by name: the name is the cargo-fuzz target's and the corpus directory's
/// (`fuzz/libfuzzer/corpus/<name>/`).
pub const TARGETS: &[(&str, Target)] = &[
    ("cdr", cdr::cdr),
    ("arbiter", arbiter::arbiter),
    ("session", session::session),
    ("config", config::config),
    ("mavlink", mavlink::mavlink),
    ("dronecan", dronecan::dronecan),
    ("replay", replay::replay),
    ("console_api", console_api::console_api),
    ("web_page", web_page::web_page),
    ("rtps", rtps::rtps),
    ("site", site::site),
];
