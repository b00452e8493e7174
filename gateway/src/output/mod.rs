//! The vehicle's output adapter as the gateway runs it: opened from `[output]`, kept in the safe
//! state while its device fails, retried, and reopened if it could not be opened at start.
//!
//! Policy: a failing output never stops the gateway. A write that fails puts the
//! outputs in the safe state (as far as the device still takes writes) and holds them there for
//! [`RETRY`]; then commands are applied again, which retries the device (the PWM backends redo a
//! channel's set-up on the next write). A device that cannot be opened at start for a transient
//! reason (a sysfs channel the kernel has not exported yet) is reopened every [`RETRY`]; a fatal
//! reason (permission denied, a channel that does not exist) ends the start with the error.
//!
//! # Layout
//! - this file: opening an adapter, [`ManagedOutput`] (the failure policy), `rove failsafe`.
//! - `worker.rs`: [`OutputWorker`], the output on a thread of its own, and [`OutputReport`].

mod worker;

pub use worker::{OutputReport, OutputWorker, WriteLimits};

use crate::config::OutputConfig;
use rove_core::MonoTime;
use rove_core::adapter::{Health, Need, OutputAdapter};
use rove_core::arbiter::Setpoint;
use rove_core::error::{Disposition, LinkError};
use std::time::Duration;
use tracing::{info, warn};

/// How long outputs stay safe after a failed write, and the reopen interval.
pub const RETRY: Duration = Duration::from_millis(250);

/// Opens the adapter `config` describes; it writes its safe state before returning.
///
/// # Errors
/// The device cannot be opened or the safe state cannot be written.
pub fn open(config: &OutputConfig, now: MonoTime) -> Result<Box<dyn OutputAdapter>, LinkError> {
    config.spec().open(now)
}

/// The output adapter with the gateway's failure policy around it.
pub struct ManagedOutput {
    config: OutputConfig,
    adapter: Option<Box<dyn OutputAdapter>>,
    /// While set: outputs held safe (or the device reopened) until then.
    hold_until: Option<MonoTime>,
    /// When the adapter's keep-alive is next due.
    next_keepalive: Option<MonoTime>,
    last_error: Option<String>,
    /// The last error of [`ManagedOutput::status`], logged once.
    last_status_error: Option<String>,
}

impl std::fmt::Debug for ManagedOutput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ManagedOutput")
            .field("adapter", &self.describe())
            .field("hold_until", &self.hold_until)
            .field("last_error", &self.last_error)
            .finish()
    }
}

impl ManagedOutput {
    /// Opens the output; a transient failure leaves it closed, to be reopened.
    ///
    /// # Errors
    /// A fatal failure to open (wrong path, no permission): the configuration must change.
    pub fn open(config: OutputConfig, now: MonoTime) -> Result<ManagedOutput, LinkError> {
        let mut managed = ManagedOutput {
            config,
            adapter: None,
            hold_until: None,
            next_keepalive: None,
            last_error: None,
            last_status_error: None,
        };
        match open(&managed.config, now) {
            Ok(adapter) => managed.adapter = Some(adapter),
            Err(e) if e.disposition == Disposition::Fatal => return Err(e),
            Err(e) => managed.failed(now, &e),
        }
        Ok(managed)
    }

    /// The adapter's description, or what is being opened.
    pub fn describe(&self) -> String {
        match &self.adapter {
            Some(a) => a.describe(),
            None => format!("{:?} (not open yet)", self.config.adapter()),
        }
    }

    /// The link's health.
    pub fn health(&self) -> Health {
        match (&self.adapter, &self.last_error) {
            (Some(a), None) => a.health(),
            (_, Some(e)) => Health::Down(e.clone()),
            (None, None) => Health::Down("not open".into()),
        }
    }

    /// What the device reports about itself (an autopilot's mode and armed state).
    pub fn detail(&self) -> Option<String> {
        self.adapter.as_ref().and_then(|a| a.detail())
    }

    /// Whether the adapter holds the outputs safe by its own decision (see
    /// [`rove_core::adapter::OutputAdapter::held_safe`]).
    pub fn held_safe(&self) -> bool {
        self.adapter.as_ref().is_some_and(|a| a.held_safe())
    }

    /// What the device says of the vehicle (nothing while the adapter is closed).
    pub fn telemetry(&self) -> rove_core::adapter::Telemetry {
        (self.adapter.as_ref()).map_or_else(Default::default, |a| a.telemetry())
    }

    /// When [`ManagedOutput::tick`] has work: the end of a hold, or the adapter's keep-alive.
    pub fn next_deadline(&self) -> Option<MonoTime> {
        let keepalive = self.adapter.as_ref().and(self.next_keepalive);
        match (self.hold_until, keepalive) {
            (Some(h), Some(k)) => Some(h.min(k)),
            (h, k) => h.or(k),
        }
    }

    /// Drives `setpoint`, unless the outputs are held safe after a failure.
    pub fn apply(&mut self, now: MonoTime, setpoint: &Setpoint) {
        if self.holding(now) {
            return;
        }
        let Some(adapter) = self.adapter.as_mut() else {
            return;
        };
        match adapter.apply(now, setpoint) {
            Ok(()) => {
                // The command was the retry and it worked: the hold is over. Left set, the next
                // tick would end it by putting the adapter, already driving, in its safe state
                // (seen against ArduPilot: a start-up hold ending in the same turn as the first command made
                // the MAVLink adapter release and command HOLD).
                self.hold_until = None;
                self.recovered();
            }
            Err(e) => {
                self.failed(now, &e);
                self.safe_state(now);
            }
        }
    }

    /// Tells the adapter what the vehicle says of itself ([`OutputAdapter::status`]); a failure
    /// is logged once per distinct message and changes nothing else.
    pub fn status(&mut self, now: MonoTime, status: &rove_core::msg::VehicleStatus) {
        let Some(adapter) = self.adapter.as_mut() else {
            return;
        };
        if let Err(e) = adapter.status(now, status)
            && self.last_status_error.as_deref() != Some(e.detail.as_str())
        {
            warn!(error = %e.detail, "the output did not take the vehicle's status");
            self.last_status_error = Some(e.detail);
        }
    }

    /// Puts the outputs in the safe state (also while holding).
    pub fn safe_state(&mut self, now: MonoTime) {
        let Some(adapter) = self.adapter.as_mut() else {
            return;
        };
        match adapter.safe_state(now) {
            Ok(()) => self.recovered_if_healthy(),
            Err(e) => self.failed(now, &e),
        }
    }

    /// Periodic work: reopen a closed output, end a hold, run the adapter's keep-alive.
    pub fn tick(&mut self, now: MonoTime) {
        if self.adapter.is_none() && !self.holding(now) {
            match open(&self.config, now) {
                Ok(adapter) => {
                    info!(output = %adapter.describe(), "output opened");
                    self.adapter = Some(adapter);
                    self.recovered();
                }
                Err(e) => self.failed(now, &e),
            }
        }
        if self.hold_until.is_some_and(|h| now >= h) {
            self.hold_until = None;
            // Still safe until the next command; that command is the retry.
            self.safe_state(now);
        }
        let due = self.next_keepalive.is_none_or(|k| now >= k);
        if let Some(adapter) = self.adapter.as_mut()
            && let Some(period) = adapter.keepalive_period()
            && due
        {
            self.next_keepalive = Some(now + period);
            match adapter.keepalive(now) {
                Ok(()) => self.recovered_if_healthy(),
                Err(e) => self.failed(now, &e),
            }
        }
    }

    fn holding(&self, now: MonoTime) -> bool {
        self.hold_until.is_some_and(|h| now < h)
    }

    fn failed(&mut self, now: MonoTime, e: &LinkError) {
        if e.disposition == Disposition::Silent {
            return;
        }
        if self.last_error.as_deref() != Some(e.detail.as_str()) {
            warn!(error = %e.detail, disposition = ?e.disposition, "output failed: outputs held safe, retrying");
        }
        self.last_error = Some(e.detail.clone());
        self.hold_until = Some(now + RETRY);
    }

    /// A keep-alive or safe-state write worked: the device is back if it says so (a CAN bus
    /// that left bus-off while nobody drives would otherwise show its old error until the
    /// next command).
    fn recovered_if_healthy(&mut self) {
        if self
            .adapter
            .as_ref()
            .is_some_and(|a| a.health() == Health::Ok)
        {
            self.recovered();
        }
    }

    fn recovered(&mut self) {
        if let Some(e) = self.last_error.take() {
            info!(previous_error = %e, "output working again");
        }
    }
}

/// Gives an output that keeps what it learns about its device ([`Need::Memory`]: a MAVLink
/// link keeps the autopilot's address and ids) its file in the [`crate::dirs::runtime_dir`]:
/// `rove failsafe` for the same vehicle reads it and reaches the device at once.
pub fn keep_learned(config: &mut OutputConfig, vehicle_id: i64) {
    if config.needs().contains(&Need::Memory)
        && let Some(dir) = crate::dirs::runtime_dir()
    {
        let file = dir.join(format!("vehicle-{vehicle_id}-{}", config.adapter()));
        config.remember_in(file);
    }
}

/// `rove failsafe`: opens the configured outputs (which writes their safe state), writes it once
/// more, and closes them (the adapters write it again on drop). For systemd's `ExecStopPost`.
///
/// # Errors
/// The outputs cannot be opened or written.
pub fn failsafe(config: &OutputConfig) -> Result<String, LinkError> {
    config.spec().failsafe()
}

#[cfg(test)]
mod tests;
