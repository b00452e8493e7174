//! The vehicle's test hooks: the SIGUSR1 stall, and the output record (`--record`).

use crate::runtime::{Clock, JsonLines};
use rove_core::arbiter::Owner;
use std::time::Duration;

/// The SIGUSR1 stall test hook, when enabled. Built in debug builds only, like the flag that
/// arms it (`--test-stall-on-sigusr1`); a release build's hook is inert.
#[cfg(debug_assertions)]
pub(super) struct StallHook(Option<(tokio::signal::unix::Signal, Duration)>);

#[cfg(debug_assertions)]
impl StallHook {
    pub(super) fn new(stall: Option<Duration>) -> anyhow::Result<StallHook> {
        use tokio::signal::unix::{SignalKind, signal};
        Ok(StallHook(match stall {
            Some(d) => Some((signal(SignalKind::user_defined1())?, d)),
            None => None,
        }))
    }

    /// Resolves with the stall length on SIGUSR1; never when the hook is off.
    pub(super) async fn requested(&mut self) -> Duration {
        match &mut self.0 {
            Some((signal, stall)) => match signal.recv().await {
                Some(()) => *stall,
                None => std::future::pending().await,
            },
            None => std::future::pending().await,
        }
    }
}

/// The release build's stall hook: never armed, never resolves.
#[cfg(not(debug_assertions))]
pub(super) struct StallHook;

#[cfg(not(debug_assertions))]
impl StallHook {
    pub(super) fn new(_stall: Option<Duration>) -> anyhow::Result<StallHook> {
        Ok(StallHook)
    }

    /// Never resolves: release builds have no stall hook.
    pub(super) async fn requested(&mut self) -> Duration {
        std::future::pending().await
    }
}

/// The sim adapter's record as JSON lines, one per output, for tests and benchmarks:
/// `{"wall_us":…,"mono_us":…,"action":"apply"|"safe","owner":id|null,"throttle":…,…}`.
pub(super) struct OutputLog(JsonLines);

impl OutputLog {
    pub(super) fn create(path: &std::path::Path) -> anyhow::Result<OutputLog> {
        JsonLines::create(path).map(OutputLog)
    }

    pub(super) fn record(
        &mut self,
        clock: &Clock,
        action: &str,
        owner: Owner,
        setpoint: Option<rove_core::arbiter::Setpoint>,
    ) {
        let mut line = serde_json::json!({
            "wall_us": clock.wall_micros(),
            "mono_us": clock.now().as_nanos() / 1_000,
            "action": action,
            "owner": owner.device(),
        });
        if let Some(sp) = setpoint {
            line["throttle"] = sp.movement.throttle.into();
            line["roll"] = sp.movement.roll.into();
            line["pitch"] = sp.movement.pitch.into();
            line["yaw"] = sp.movement.yaw.into();
            line["mode"] = (sp.mode as u32).into();
        }
        self.0.write(&line);
    }
}
