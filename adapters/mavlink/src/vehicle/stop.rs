//! Stopping the MAVLink vehicle: on drop, the safe state and then a bounded wait for the
//! autopilot to confirm the safe mode; and `rove failsafe` ([`failsafe`]), the same from a
//! process of its own, starting from what the running vehicle learned.

use super::{MavlinkVehicle, STOP_ACK_WAIT};
use crate::config::{AutopilotMode, MavlinkConfig};
use crate::link::LinkStatus;
use crate::memory::Learned;
use crate::mode::ModeState;
use rove_core::MonoTime;
use rove_core::adapter::OutputAdapter;
use rove_core::error::LinkError;
use std::time::{Duration, Instant};
use tracing::{info, warn};

impl MavlinkVehicle {
    /// Steps the adapter with wall time until the mode machine settles or `limit` passes.
    fn settle_mode(&mut self, limit: Duration) {
        let deadline = Instant::now() + limit;
        while matches!(self.mode.state(), ModeState::Pending { .. }) && Instant::now() < deadline {
            let seen = self.link.generation();
            let now = self.now_from_clock();
            if self.keepalive(now).is_err() && self.link.target().is_none() {
                break;
            }
            if !matches!(self.mode.state(), ModeState::Pending { .. }) {
                break;
            }
            // Woken by the autopilot's answer, else at the next resend or keep-alive.
            let next = self
                .mode
                .next_deadline()
                .map_or(self.period, |d| d.saturating_since(now))
                .min(self.period)
                .min(deadline.saturating_duration_since(Instant::now()));
            self.link.wait_for_news(seen, next);
        }
    }

    /// The bound on waiting for a mode command: every send's timeout, plus one.
    fn mode_wait(&self) -> Duration {
        self.config.command_timeout * (self.config.command_retries + 2)
    }
}

impl Drop for MavlinkVehicle {
    fn drop(&mut self) {
        let now = self.now_from_clock();
        if self.safe_state(now).is_err() {
            return;
        }
        // A safe mode already confirmed is not requested again (nothing is pending then).
        self.settle_mode(self.mode_wait().min(STOP_ACK_WAIT));
    }
}

/// `rove failsafe` for a MAVLink vehicle: connect, address the autopilot, release (or
/// neutral), command the safe mode and wait for its confirmation.
///
/// It starts from what the running vehicle learned ([`crate::memory`], `config.memory`): the
/// autopilot's ids and, on a `udpin:` link, its address. With them (or `target_system` on a link
/// that needs no address) the messages leave as soon as the transport is open and the
/// COMMAND_ACK ends the command within milliseconds. Without, it waits (bounded by the link
/// timeout) for the autopilot to speak: its HEARTBEAT comes once a second.
///
/// # Errors
/// Nobody to address within the link timeout (the message says what was missing), the messages
/// cannot be sent, or the safe mode was refused or not confirmed.
pub fn failsafe(config: &MavlinkConfig) -> Result<String, LinkError> {
    let start = Instant::now();
    let endpoint = config.endpoint.to_string();
    let learned = match config
        .memory
        .as_deref()
        .map(|p| Learned::load(p, &endpoint))
    {
        Some(Ok(learned)) => learned,
        Some(Err(why)) => {
            warn!(%why, "mavlink: what the vehicle learned is not used");
            None
        }
        None => None,
    };
    // The file is the running vehicle's: read here, never written (a one-shot process killed
    // by systemd mid-write would leave half of it behind). Nor are its ground stations' ports: the vehicle is routing them.
    let read_only = MavlinkConfig {
        memory: None,
        gcs: Vec::new(),
        ..config.clone()
    };
    let mut v = MavlinkVehicle::start(read_only, MonoTime::ZERO, learned.as_ref())?;
    let ready = |v: &MavlinkVehicle| v.link.target().is_some() && v.link.can_send();
    while !ready(&v) && start.elapsed() < config.link_timeout {
        let seen = v.link.generation();
        let now = v.now_from_clock();
        let _ = v.keepalive(now);
        // The autopilot's first datagram or HEARTBEAT wakes this at once.
        v.link.wait_for_news(seen, v.period);
    }
    if !ready(&v) {
        let status = v.link.status();
        let missing = if !status.connected {
            format!(
                "the link did not open ({})",
                status.error.as_deref().unwrap_or("connecting")
            )
        } else if v.link.target().is_none() {
            "no HEARTBEAT from an autopilot, and no system id known (set target_system)".into()
        } else {
            "no datagram from the autopilot, so no address to send to".into()
        };
        return Err(LinkError::transient(format!(
            "mavlink {endpoint}: nothing sent: {missing} within {:?}; {}",
            config.link_timeout,
            match (&config.memory, &learned) {
                (None, _) => "no runtime directory to learn the autopilot from".to_string(),
                (Some(p), None) => format!("no running vehicle had written {}", p.display()),
                (Some(p), Some(l)) => format!("{} had {l}", p.display()),
            }
        )));
    }
    if let Some(l) = &learned {
        info!(learned = %l, "mavlink: addressing the autopilot the vehicle learned");
    }
    v.failsafe_now()
}

impl MavlinkVehicle {
    /// `rove failsafe`'s work once the autopilot is known: release (or neutral), command the
    /// safe mode, and wait (bounded) for its confirmation.
    ///
    /// # Errors
    /// The messages cannot be sent, or the safe mode was refused or not confirmed in time.
    pub fn failsafe_now(&mut self) -> Result<String, LinkError> {
        let v = self;
        let now = v.now_from_clock();
        // `rove failsafe` releases at once, start-up grace or not.
        v.fresh = false;
        v.command_safe_mode(now);
        v.safe_state(now)?;
        v.settle_mode(v.mode_wait());
        v.failsafe_result()
    }

    fn failsafe_result(&self) -> Result<String, LinkError> {
        let v = self;
        match v.mode.state() {
            ModeState::Failed { reason, .. } => Err(LinkError::transient(reason.clone())),
            ModeState::Pending { mode, .. } => Err(LinkError::transient(format!(
                "{} not confirmed in time",
                mode.name
            ))),
            ModeState::Confirmed(mode) => Ok(format!(
                "{} — {}",
                v.describe(),
                confirmation(&v.link.status(), mode, |m| v.mode_name(m))
            )),
            ModeState::Idle => Ok(format!(
                "{} — {}; no mode commanded (set_mode = false)",
                v.describe(),
                v.autopilot_summary()
            )),
        }
    }
}

/// What `rove failsafe` says of a confirmed safe mode: who confirmed it, and how. A COMMAND_ACK
/// is as good an answer as a HEARTBEAT; a HEARTBEAT that still shows the mode before is named as
/// such (pure, unit-tested).
pub(super) fn confirmation(
    status: &LinkStatus,
    mode: &AutopilotMode,
    name: impl Fn(u32) -> String,
) -> String {
    match (status.autopilot, status.acked_by) {
        (Some(a), _) if a.custom_mode == mode.custom_mode => format!(
            "system {}/{} in {}, {}",
            a.system_id,
            a.component_id,
            mode.name,
            if a.armed { "armed" } else { "disarmed" }
        ),
        (Some(a), _) => format!(
            "system {}/{} acknowledged {} (its last HEARTBEAT, older, said {}), {}",
            a.system_id,
            a.component_id,
            mode.name,
            name(a.custom_mode),
            if a.armed { "armed" } else { "disarmed" }
        ),
        (None, Some((sys, comp))) => format!(
            "system {sys}/{comp} acknowledged {} (COMMAND_ACK; no HEARTBEAT heard yet)",
            mode.name
        ),
        (None, None) => format!("{} confirmed", mode.name),
    }
}
