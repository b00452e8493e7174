//! The MAVLink vehicle: rove's [`OutputAdapter`] for an ArduPilot or PX4 autopilot.
//!
//! | call | sends |
//! |---|---|
//! | `apply` | the control message for the setpoint (RC_CHANNELS_OVERRIDE or MANUAL_CONTROL) at once; a mode command when the wished mode changed |
//! | `keepalive` (every `1/rate_hz`) | the GCS HEARTBEAT when 1 s has passed; while driving, the control message again; in failsafe, neutral sticks (`failsafe = "neutral"`) or the release message ([`RELEASE_SENDS`] times, then nothing); mode command resends |
//! | `safe_state` | release or neutral at once; the safe mode, if rove was driving |
//! | drop | as `safe_state`, then waits (bounded) for the safe mode's confirmation |
//!
//! The safe mode is commanded only when rove *stops* driving (or by [`failsafe`]), never at
//! start: a gateway restarting must not yank a vehicle a pilot is flying on the radio into HOLD.

use crate::config::{FailsafeAction, MavlinkConfig, Method};
use crate::encode::{RC_CHANNELS, manual_control_values, override_values, release_values};
use crate::link::{Link, LinkStatus};
use crate::mode::{ModeControl, ModeState};
use mavlink::dialects::ardupilotmega::{
    COMMAND_LONG_DATA, HEARTBEAT_DATA, MANUAL_CONTROL_DATA, MavAutopilot, MavCmd, MavMessage,
    MavModeFlag, MavState, MavType, RC_CHANNELS_OVERRIDE_DATA,
};
use rove_core::MonoTime;
use rove_core::adapter::{Health, OutputAdapter};
use rove_core::arbiter::Setpoint;
use rove_core::error::LinkError;
use rove_core::msg::MovementCommand;
use std::time::{Duration, Instant};
use tracing::{info, warn};

/// GCS HEARTBEAT period (MAVLink: 1 Hz).
pub const HEARTBEAT_PERIOD: Duration = Duration::from_secs(1);
/// Release messages sent on entering failsafe (one at once, the rest at the resend rate), so
/// a lost UDP datagram does not leave a channel overridden until the autopilot's timeout.
pub const RELEASE_SENDS: u32 = 3;
/// MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, DO_SET_MODE's param1.
const CUSTOM_MODE_ENABLED: f32 = 1.0;

/// What the adapter is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Drive {
    /// Driving these values.
    Driving(Setpoint),
    /// In failsafe; `releases_left` release messages still to send.
    Safe { releases_left: u32 },
}

/// An autopilot driven over MAVLink.
#[derive(Debug)]
pub struct MavlinkVehicle {
    config: MavlinkConfig,
    link: Link,
    drive: Drive,
    mode: ModeControl,
    next_heartbeat: MonoTime,
    /// Whether the autopilot was heard within the link timeout at the last step.
    link_up: bool,
    /// Maps the caller's `now` to wall time for [`Drop`], which gets no `now`.
    clock: (MonoTime, Instant),
}

impl MavlinkVehicle {
    /// Starts the link (connecting in the background) and enters the safe state.
    ///
    /// # Errors
    /// The link's thread cannot start.
    pub fn new(config: MavlinkConfig, now: MonoTime) -> Result<MavlinkVehicle, LinkError> {
        let link = Link::start(&config)?;
        let mode = ModeControl::new(config.command_timeout, config.command_retries);
        info!(
            endpoint = %config.endpoint,
            system_id = config.system_id,
            component_id = config.component_id,
            method = ?config.method,
            "mavlink: acting as a ground station"
        );
        Ok(MavlinkVehicle {
            config,
            link,
            drive: Drive::Safe {
                releases_left: RELEASE_SENDS,
            },
            mode,
            next_heartbeat: now,
            link_up: false,
            clock: (now, Instant::now()),
        })
    }

    /// The link's state (for tests and status displays).
    pub fn link_status(&self) -> LinkStatus {
        self.link.status()
    }

    /// The mode machine's state.
    pub fn mode_state(&self) -> &ModeState {
        self.mode.state()
    }

    /// Commands the safe mode even though rove was not driving (`rove failsafe`).
    pub fn command_safe_mode(&mut self, now: MonoTime) {
        if self.config.modes.set_mode {
            self.mode.request(now, &self.config.modes.safe);
        }
    }

    fn heard_recently(&self, status: &LinkStatus) -> bool {
        status
            .last_heartbeat
            .is_some_and(|t| t.elapsed() <= self.config.link_timeout)
    }

    /// Feeds what the link heard into the mode machine; reports link changes.
    fn observe(&mut self, now: MonoTime) {
        let status = self.link.status();
        for ack in self.link.take_acks() {
            self.mode.on_ack(now, ack);
        }
        if let Some(a) = status.autopilot {
            self.mode.on_heartbeat(a.custom_mode);
        }
        let up = self.heard_recently(&status);
        if up != self.link_up {
            self.link_up = up;
            if up {
                info!(endpoint = %self.config.endpoint, "mavlink: autopilot heard");
                // ArduPilot leaves a GCS failsafe in HOLD: say again what rove wants.
                self.mode.reassert(now);
            } else {
                warn!(
                    endpoint = %self.config.endpoint,
                    timeout = ?self.config.link_timeout,
                    "mavlink: no HEARTBEAT from the autopilot"
                );
            }
        }
    }

    fn target(&self) -> Result<(u8, u8), LinkError> {
        self.link.target().ok_or_else(|| {
            LinkError::transient(format!(
                "mavlink {}: no autopilot heard yet",
                self.config.endpoint
            ))
        })
    }

    fn send_heartbeat_if_due(&mut self, now: MonoTime) -> Result<(), LinkError> {
        if now < self.next_heartbeat {
            return Ok(());
        }
        self.link.send(&MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode: 0,
            mavtype: MavType::MAV_TYPE_GCS,
            autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
            base_mode: MavModeFlag::empty(),
            system_status: MavState::MAV_STATE_ACTIVE,
            mavlink_version: 3,
        }))?;
        // Advanced only on success: a link that comes up gets a heartbeat at once.
        self.next_heartbeat = now + HEARTBEAT_PERIOD;
        Ok(())
    }

    fn send_control(&self, movement: &MovementCommand) -> Result<(), LinkError> {
        let (sys, comp) = self.target()?;
        let msg = match self.config.method {
            Method::RcOverride => {
                rc_override(sys, comp, &override_values(&self.config.channels, movement))
            }
            Method::ManualControl => {
                let [x, y, z, r] = manual_control_values(&self.config.manual_control, movement);
                MavMessage::MANUAL_CONTROL(MANUAL_CONTROL_DATA {
                    x,
                    y,
                    z,
                    r,
                    target: sys,
                    ..MANUAL_CONTROL_DATA::default()
                })
            }
        };
        self.link.send(&msg)
    }

    fn send_release(&self) -> Result<(), LinkError> {
        let (sys, comp) = self.target()?;
        self.link.send(&rc_override(
            sys,
            comp,
            &release_values(&self.config.channels),
        ))
    }

    fn send_mode_if_due(&mut self, now: MonoTime) -> Result<(), LinkError> {
        let Some((sys, comp)) = self.link.target() else {
            return Ok(()); // the first send waits for the autopilot
        };
        let Some(custom_mode) = self.mode.poll(now) else {
            return Ok(());
        };
        let (param2, param3) = match self.config.autopilot {
            crate::config::AutopilotKind::Ardupilot => (custom_mode as f32, 0.0),
            crate::config::AutopilotKind::Px4 => (
                ((custom_mode >> 16) & 0xff) as f32,
                ((custom_mode >> 24) & 0xff) as f32,
            ),
        };
        self.link.send(&MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
            param1: CUSTOM_MODE_ENABLED,
            param2,
            param3,
            command: MavCmd::MAV_CMD_DO_SET_MODE,
            target_system: sys,
            target_component: comp,
            ..COMMAND_LONG_DATA::default()
        }))
    }

    /// The failsafe message for this step, if any.
    fn send_failsafe(&mut self) -> Result<(), LinkError> {
        match (self.config.failsafe, &mut self.drive) {
            (FailsafeAction::Neutral, _) => self.send_control(&MovementCommand::CENTRED),
            (FailsafeAction::Release, Drive::Safe { releases_left }) if *releases_left > 0 => {
                *releases_left -= 1;
                self.send_release()
            }
            _ => Ok(()),
        }
    }

    fn now_from_clock(&self) -> MonoTime {
        self.clock.0 + self.clock.1.elapsed()
    }
}

fn rc_override(sys: u8, comp: u8, v: &[u16; RC_CHANNELS]) -> MavMessage {
    MavMessage::RC_CHANNELS_OVERRIDE(RC_CHANNELS_OVERRIDE_DATA {
        target_system: sys,
        target_component: comp,
        chan1_raw: v[0],
        chan2_raw: v[1],
        chan3_raw: v[2],
        chan4_raw: v[3],
        chan5_raw: v[4],
        chan6_raw: v[5],
        chan7_raw: v[6],
        chan8_raw: v[7],
        chan9_raw: v[8],
        chan10_raw: v[9],
        chan11_raw: v[10],
        chan12_raw: v[11],
        chan13_raw: v[12],
        chan14_raw: v[13],
        chan15_raw: v[14],
        chan16_raw: v[15],
        chan17_raw: v[16],
        chan18_raw: v[17],
    })
}

/// Keeps the first error of several sends (all are attempted).
fn first_error(results: [Result<(), LinkError>; 3]) -> Result<(), LinkError> {
    results
        .into_iter()
        .collect::<Result<Vec<()>, _>>()
        .map(|_| ())
}

impl OutputAdapter for MavlinkVehicle {
    fn describe(&self) -> String {
        format!(
            "mavlink {} ({:?} {:?}, {}, GCS {}/{})",
            self.config.endpoint,
            self.config.autopilot,
            self.config.vehicle,
            match self.config.method {
                Method::RcOverride => "RC_CHANNELS_OVERRIDE",
                Method::ManualControl => "MANUAL_CONTROL",
            },
            self.config.system_id,
            self.config.component_id
        )
    }

    fn apply(&mut self, now: MonoTime, setpoint: &Setpoint) -> Result<(), LinkError> {
        self.clock = (now, Instant::now());
        self.observe(now);
        self.drive = Drive::Driving(*setpoint);
        if self.config.modes.set_mode {
            let wished = self.config.modes.for_mode(setpoint.mode).clone();
            self.mode.request(now, &wished);
        }
        // The control message first: it is what the latency budget is about.
        let control = self.send_control(&setpoint.movement);
        let mode = self.send_mode_if_due(now);
        let heartbeat = self.send_heartbeat_if_due(now);
        first_error([control, mode, heartbeat])
    }

    fn safe_state(&mut self, now: MonoTime) -> Result<(), LinkError> {
        self.clock = (now, Instant::now());
        self.observe(now);
        let was_driving = matches!(self.drive, Drive::Driving(_));
        if was_driving {
            self.drive = Drive::Safe {
                releases_left: RELEASE_SENDS,
            };
        }
        if was_driving && self.config.modes.set_mode {
            self.mode.request(now, &self.config.modes.safe);
        }
        let control = match self.link.target() {
            // Nothing to release on an autopilot never heard.
            None => Ok(()),
            Some(_) => self.send_failsafe(),
        };
        let mode = self.send_mode_if_due(now);
        let heartbeat = self.send_heartbeat_if_due(now);
        first_error([control, mode, heartbeat])
    }

    fn keepalive_period(&self) -> Option<Duration> {
        Some(self.config.period)
    }

    fn keepalive(&mut self, now: MonoTime) -> Result<(), LinkError> {
        self.clock = (now, Instant::now());
        self.observe(now);
        let heartbeat = self.send_heartbeat_if_due(now);
        let control = match self.drive {
            Drive::Driving(setpoint) => self.send_control(&setpoint.movement),
            Drive::Safe { .. } if self.link.target().is_some() => self.send_failsafe(),
            Drive::Safe { .. } => Ok(()),
        };
        let mode = self.send_mode_if_due(now);
        first_error([heartbeat, control, mode])
    }

    fn health(&self) -> Health {
        let status = self.link.status();
        if !status.connected {
            return Health::Down(format!(
                "{}: {}",
                self.config.endpoint,
                status.error.as_deref().unwrap_or("connecting")
            ));
        }
        let Some(a) = status.autopilot else {
            return Health::Down(format!("{}: no autopilot heard yet", self.config.endpoint));
        };
        if !self.heard_recently(&status) {
            return Health::Down(format!(
                "{}: no HEARTBEAT from system {} for over {:?}",
                self.config.endpoint, a.system_id, self.config.link_timeout
            ));
        }
        match self.mode.state() {
            ModeState::Failed { reason, .. } => Health::Degraded(reason.clone()),
            _ => Health::Ok,
        }
    }

    fn detail(&self) -> Option<String> {
        Some(self.autopilot_summary())
    }
}

impl MavlinkVehicle {
    /// A line for status displays: the autopilot, its mode and armed state.
    pub fn autopilot_summary(&self) -> String {
        let status = self.link.status();
        match status.autopilot {
            None => "no autopilot heard".into(),
            Some(a) => {
                let mode = crate::config::mode_table(self.config.autopilot, self.config.vehicle)
                    .into_iter()
                    .find(|&(_, m)| m == a.custom_mode)
                    .map_or_else(|| format!("mode {}", a.custom_mode), |(n, _)| n.to_string());
                format!(
                    "system {} ({:?}), {mode}, {}",
                    a.system_id,
                    self.config.autopilot,
                    if a.armed { "armed" } else { "disarmed" }
                )
            }
        }
    }

    /// Steps the adapter with wall time until the mode machine settles or `limit` passes.
    fn settle_mode(&mut self, limit: Duration) {
        let deadline = Instant::now() + limit;
        while matches!(self.mode.state(), ModeState::Pending { .. }) && Instant::now() < deadline {
            let now = self.now_from_clock();
            if self.keepalive(now).is_err() && self.link.target().is_none() {
                break;
            }
            std::thread::sleep(Duration::from_millis(10));
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
        self.settle_mode(self.mode_wait());
    }
}

/// `rove failsafe` for a MAVLink vehicle: connect, wait (bounded by the link timeout) for the
/// autopilot, release (or neutral), command the safe mode and wait for its confirmation.
///
/// # Errors
/// The autopilot was not heard, or the safe mode was not confirmed.
pub fn failsafe(config: &MavlinkConfig) -> Result<String, LinkError> {
    let start = Instant::now();
    let mut v = MavlinkVehicle::new(config.clone(), MonoTime::ZERO)?;
    while v.link.target().is_none() && start.elapsed() < config.link_timeout {
        let now = v.now_from_clock();
        let _ = v.keepalive(now);
        std::thread::sleep(Duration::from_millis(20));
    }
    v.target()?;
    let now = v.now_from_clock();
    v.command_safe_mode(now);
    v.safe_state(now)?;
    v.settle_mode(v.mode_wait());
    match v.mode.state() {
        ModeState::Failed { reason, .. } => Err(LinkError::transient(reason.clone())),
        ModeState::Pending { mode, .. } => Err(LinkError::transient(format!(
            "{} not confirmed in time",
            mode.name
        ))),
        _ => Ok(format!("{} — {}", v.describe(), v.autopilot_summary())),
    }
}
