//! The messages the MAVLink vehicle sends: the GCS HEARTBEAT, the control message
//! (RC_CHANNELS_OVERRIDE or MANUAL_CONTROL) within the serial byte budget and never ahead of
//! its mode, the release, the mode command (DO_SET_MODE) and the failsafe content.

use super::{
    CUSTOM_MODE_ENABLED, Drive, HEARTBEAT_PERIOD, KEEPALIVE_SKIP, MavlinkVehicle,
    START_RELEASE_GRACE,
};
use crate::config::{FailsafeAction, Method};
use crate::encode::{RC_CHANNELS, manual_control_values, override_values, release_values};
use crate::mode::ModeState;
use mavlink::dialects::ardupilotmega::{
    COMMAND_LONG_DATA, HEARTBEAT_DATA, MANUAL_CONTROL_DATA, MavAutopilot, MavCmd, MavMessage,
    MavModeFlag, MavState, MavType, RC_CHANNELS_OVERRIDE_DATA,
};
use rove_core::MonoTime;
use rove_core::error::{Disposition, LinkError};
use rove_core::msg::MovementCommand;
use std::time::Instant;

impl MavlinkVehicle {
    fn target(&self) -> Result<(u8, u8), LinkError> {
        self.link.target().ok_or_else(|| {
            LinkError::transient(format!(
                "mavlink {}: no autopilot heard yet",
                self.config.endpoint
            ))
        })
    }

    pub(super) fn send_heartbeat_if_due(&mut self, now: MonoTime) -> Result<(), LinkError> {
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

    /// Whether the serial byte budget lets a control message leave now.
    pub(super) fn budget_allows(&self, now: MonoTime) -> bool {
        self.last_control.is_none_or(|t| now >= t + self.min_gap)
    }

    /// Whether the keep-alive should repeat the control message (none left recently).
    pub(super) fn keepalive_due(&self, now: MonoTime) -> bool {
        let skip = self.period.mul_f64(KEEPALIVE_SKIP);
        self.last_control
            .is_none_or(|t| now >= t + skip.max(self.min_gap))
    }

    fn send_control(&mut self, now: MonoTime, movement: &MovementCommand) -> Result<(), LinkError> {
        let (sys, comp) = self.target()?;
        if !self.may_control() {
            // Another station holds the role ([`Self::may_control`]): rove asks, and waits.
            self.deferred = false;
            return Ok(());
        }
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
        self.link.send(&msg)?;
        self.last_control = Some(now);
        self.deferred = false;
        Ok(())
    }

    /// Whether the operator's sticks wait for the autopilot to take the operator's mode: a mode
    /// was asked for and is neither acknowledged nor reported by a HEARTBEAT yet.
    ///
    /// Sticks are meant for the mode they come with. Sent before the autopilot took it, they act
    /// in the mode before (seen: a Rover refusing AUTO ran the AUTO request's throttle in MANUAL
    /// for ~60 ms). So until then no control message leaves: the autopilot keeps what it last
    /// had from rove in the mode it is in (an override lasts `RC_OVERRIDE_TIME`, 3 s; the wait
    /// is bounded by the mode command's resends), and nothing it was not given for that mode
    /// arrives — neither the new sticks nor a release (a vehicle starting under a streaming
    /// operator must not blip the radio's values). The cost is one COMMAND_ACK round trip
    /// (20–45 ms on ArduPilot) of the previous values at a mode change; a mode the autopilot
    /// already reports costs nothing. A refusal then puts the outputs in their safe state.
    fn sticks_wait(&self) -> bool {
        let ModeState::Pending { mode, .. } = self.mode.state() else {
            return false;
        };
        (self.link.status().autopilot).is_none_or(|a| a.custom_mode != mode.custom_mode)
    }

    /// The operator's sticks, unless they wait for their mode ([`Self::sticks_wait`]).
    pub(super) fn send_sticks(
        &mut self,
        now: MonoTime,
        movement: &MovementCommand,
    ) -> Result<(), LinkError> {
        if self.sticks_wait() {
            self.deferred = false;
            return Ok(());
        }
        self.send_control(now, movement)
    }

    fn send_release(&mut self, now: MonoTime) -> Result<(), LinkError> {
        let (sys, comp) = self.target()?;
        if !self.may_control() {
            return Ok(());
        }
        self.link.send(&rc_override(
            sys,
            comp,
            &release_values(&self.config.channels),
        ))?;
        self.last_control = Some(now);
        Ok(())
    }

    pub(super) fn send_mode_if_due(&mut self, now: MonoTime) -> Result<(), LinkError> {
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
        self.mode_sent = Some(Instant::now());
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
    pub(super) fn send_failsafe(&mut self, now: MonoTime) -> Result<(), LinkError> {
        if self.fresh && self.heard_at.is_none_or(|t| now < t + START_RELEASE_GRACE) {
            return Ok(());
        }
        match (self.config.failsafe, &mut self.drive) {
            (FailsafeAction::Neutral, _) => self.send_control(now, &MovementCommand::CENTRED),
            (FailsafeAction::Release, Drive::Safe { releases_left }) if *releases_left > 0 => {
                *releases_left -= 1;
                self.send_release(now)
            }
            _ => Ok(()),
        }
    }

    /// Until the autopilot is first heard, a send that fails (the transport still opening, a
    /// udpin link before the autopilot's first datagram) is routine: the health says why
    /// ("connecting", "no autopilot heard yet") and the link thread logs a transport that cannot
    /// open. Reported as silent so that the gateway neither logs an output failure nor holds the
    /// outputs at start. Once the autopilot was heard, failures are transient.
    pub(super) fn connecting(&self, e: LinkError) -> LinkError {
        if self.link.first_connect_pending() || self.heard_at.is_none() {
            LinkError {
                disposition: Disposition::Silent,
                ..e
            }
        } else {
            e
        }
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
pub(super) fn first_error(results: [Result<(), LinkError>; 3]) -> Result<(), LinkError> {
    results
        .into_iter()
        .collect::<Result<Vec<()>, _>>()
        .map(|_| ())
}
