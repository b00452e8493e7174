//! rove's end-to-end tests: the real `rove` binary as processes, each test in a network namespace
//! of its own (as root, with iproute2), asserting on outputs, records, status and logs. One test
//! binary, a module per area (as ripgrep's `tests/tests.rs`); what they share is in [`util`].
//!
//! The target is declared in `gateway/Cargo.toml` (the package that builds `rove`, so Cargo
//! sets `CARGO_BIN_EXE_rove`): `cargo test -p rove-gateway --test e2e [MODULE::]`.

mod util;

mod audit;
mod boards;
mod console_api;
mod fleet;
mod flood;
mod gcs;
mod hierarchy;
mod inputs;
mod mavlink;
mod outputs;
mod package;
mod robustness;
mod ros2;
mod security;
mod service;
#[cfg(all(feature = "remote", feature = "security"))]
mod sites;
mod spray;
mod stop;
mod tools;
mod trust;
mod web;
