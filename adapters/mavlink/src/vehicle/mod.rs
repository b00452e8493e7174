//! The MAVLink vehicle: rove's [`OutputAdapter`] for an ArduPilot or PX4 autopilot.
//!
//! | call | sends |
//! |---|---|
//! | `apply` | the control message for the setpoint (RC_CHANNELS_OVERRIDE or MANUAL_CONTROL) at once — nothing while a new mode waits for the autopilot to take it; a mode command when the wished mode changed |
//! | `keepalive` (every `1/rate_hz`) | the GCS HEARTBEAT when 1 s has passed; while driving, the control message again unless one left within [`KEEPALIVE_SKIP`] of the period (one override per period, not one per command *plus* one per period); in failsafe, neutral sticks (`failsafe = "neutral"`) or the release message ([`RELEASE_SENDS`] times, then nothing); mode command resends |
//! | `safe_state` | release or neutral at once; the safe mode, if rove was driving |
//! | drop | as `safe_state`, then waits (bounded) for the safe mode's confirmation |
//!
//! The safe mode is commanded only when rove *stops* driving (or by [`failsafe`]), never at
//! start: a gateway restarting must not yank a vehicle a pilot is flying on the radio into HOLD.
//!
//! A driven mode the autopilot refuses (ArduPilot Rover: AUTO without a mission →
//! MAV_RESULT_FAILED) is logged once, shown in the health and detail, and with
//! `on_mode_refused = "hold"` (the default) rove stops driving: failsafe content and the safe
//! mode, until the operator's mode changes.
//!
//! On a serial link the control messages are kept within [`SERIAL_SHARE`] of the link's bytes
//! (8N1: baud / 10 bytes/s): a rate above it is lowered, with a logged note, and commands that
//! come faster are coalesced (the newest is sent when the budget allows).
//!
//! # Layout
//! - this file: [`MavlinkVehicle`], its start, what it makes of what the link hears (mode
//!   confirmations, refusals, the link coming and going), and its [`OutputAdapter`] calls.
//! - `send.rs`: the messages it sends: HEARTBEAT, the control message within the serial
//!   budget, release, the mode command, the failsafe content.
//! - `stop.rs`: stopping: the drop's bounded wait for the safe mode, and [`failsafe`] (`rove
//!   failsafe`).

mod manager;
mod send;
mod stop;

pub use stop::failsafe;

use crate::config::AutopilotMode;
use crate::config::{Endpoint, MavlinkConfig, Method, OnModeRefused};
use crate::link::{Link, LinkStatus};
use crate::memory::Learned;
use crate::mode::{ModeControl, ModeState};
use mavlink::dialects::ardupilotmega::{MANUAL_CONTROL_DATA, RC_CHANNELS_OVERRIDE_DATA};
use rove_core::MonoTime;
use rove_core::adapter::{Health, OutputAdapter, Telemetry};
use rove_core::arbiter::Setpoint;
use rove_core::error::{Disposition, LinkError};
use send::first_error;
use std::time::{Duration, Instant};
use tracing::{info, warn};

/// GCS HEARTBEAT period (MAVLink: 1 Hz).
pub const HEARTBEAT_PERIOD: Duration = Duration::from_secs(1);
/// Release messages sent on entering failsafe (one at once, the rest at the resend rate), so
/// a lost UDP datagram does not leave a channel overridden until the autopilot's timeout.
pub const RELEASE_SENDS: u32 = 3;
/// The keep-alive skips the control message when one left less than this fraction of the period
/// ago (a command did): 3/4 rather than 1 so that the keep-alive's own phase jitter does not
/// double a send; the longest gap when commands stop is then under 1.75 periods.
pub const KEEPALIVE_SKIP: f64 = 0.75;
/// Share of a serial link's bytes the control messages may use; the rest is for the heartbeat,
/// mode commands and, on half-duplex radios (SiK), the autopilot's telemetry.
pub const SERIAL_SHARE: f64 = 0.5;
/// At start, the release (or neutral sticks) waits this long after the autopilot is first heard,
/// and is not sent at all if a command comes first: an operator already streaming (the arbiter
/// drops one silent for 100 ms, so a live one sends faster than that) would otherwise see its
/// first override preceded by a release, a blip of radio values. A restart after a
/// crash still releases, 250 ms late (`rove failsafe` in ExecStopPost releases at once).
pub const START_RELEASE_GRACE: Duration = Duration::from_millis(250);
/// How long a stopping adapter waits for the autopilot to confirm the safe mode before it closes
/// the link. ArduPilot does not act on what a TCP client wrote just before closing (it drops the
/// connection's unread bytes), so the COMMAND_ACK is the proof the release and the mode were
/// read. ArduPilot answers DO_SET_MODE in 20–45 ms over TCP.
pub const STOP_ACK_WAIT: Duration = Duration::from_millis(300);
/// MAVLink 2 header (10) and CRC (2) around a payload; MAVLink 1: 6 + 2.
const V2_OVERHEAD: usize = 12;
const V1_OVERHEAD: usize = 8;
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
    /// Whether it was ever heard (a link coming up again is a return, not a first contact).
    heard_before: bool,
    /// When the last mode command left.
    mode_sent: Option<Instant>,
    /// Maps the caller's `now` to wall time for [`Drop`], which gets no `now`.
    clock: (MonoTime, Instant),
    /// When the last control message (override, MANUAL_CONTROL, release) left.
    last_control: Option<MonoTime>,
    /// The keep-alive period: `rate_hz`, or slower if a serial link's byte budget needs it.
    period: Duration,
    /// Serial byte budget: the shortest spacing of control messages (zero on UDP/TCP).
    min_gap: Duration,
    /// A command not sent yet because of `min_gap`: the keep-alive sends it.
    deferred: bool,
    /// A driven mode the autopilot refused (or never confirmed), and why.
    refused: Option<(AutopilotMode, String)>,
    /// Not driven since start: the start-up failsafe content waits for [`START_RELEASE_GRACE`].
    fresh: bool,
    /// When the autopilot's first HEARTBEAT was seen.
    heard_at: Option<MonoTime>,
    /// Commands arrived before the autopilot was heard (logged once).
    warned_unheard: bool,
    /// When rove last asked the autopilot's system manager for control ([`manager`]).
    asking: crate::control::Asking,
}

/// The shortest spacing of control messages a serial link at `baud` (8N1) carries within
/// `share` of its bytes, for frames of `frame_bytes` (pure, unit-tested).
pub fn serial_min_gap(baud: u32, frame_bytes: usize, share: f64) -> Duration {
    let bytes_per_s = f64::from(baud) / 10.0 * share;
    if bytes_per_s <= 0.0 {
        return Duration::from_secs(1);
    }
    Duration::from_secs_f64((frame_bytes as f64 / bytes_per_s).min(1.0))
}

/// The largest control frame this configuration sends, in bytes.
pub fn control_frame_bytes(config: &MavlinkConfig) -> usize {
    let payload = match config.method {
        Method::RcOverride => RC_CHANNELS_OVERRIDE_DATA::ENCODED_LEN,
        Method::ManualControl => MANUAL_CONTROL_DATA::ENCODED_LEN,
    };
    payload
        + if config.mavlink_version == 1 {
            V1_OVERHEAD
        } else {
            V2_OVERHEAD
        }
}

impl MavlinkVehicle {
    /// Starts the link (connecting in the background) and enters the safe state.
    ///
    /// # Errors
    /// The link's thread cannot start.
    pub fn new(config: MavlinkConfig, now: MonoTime) -> Result<MavlinkVehicle, LinkError> {
        MavlinkVehicle::start(config, now, None)
    }

    fn start(
        config: MavlinkConfig,
        now: MonoTime,
        learned: Option<&Learned>,
    ) -> Result<MavlinkVehicle, LinkError> {
        let link = Link::start_from(&config, learned)?;
        let mode = ModeControl::new(config.command_timeout, config.command_retries);
        let min_gap = match &config.endpoint {
            Endpoint::Serial { baud, .. } => {
                serial_min_gap(*baud, control_frame_bytes(&config), SERIAL_SHARE)
            }
            _ => Duration::ZERO,
        };
        let period = config.period.max(min_gap);
        if period > config.period {
            info!(
                endpoint = %config.endpoint,
                rate_hz = 1.0 / config.period.as_secs_f64(),
                lowered_to_hz = 1.0 / period.as_secs_f64(),
                frame_bytes = control_frame_bytes(&config),
                "mavlink: control rate lowered to fit the serial link's byte budget"
            );
        }
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
            heard_before: false,
            mode_sent: None,
            clock: (now, Instant::now()),
            last_control: None,
            period,
            min_gap,
            deferred: false,
            refused: None,
            fresh: true,
            heard_at: None,
            warned_unheard: false,
            asking: crate::control::Asking::default(),
        })
    }

    /// The link's state (for tests and status displays).
    pub fn link_status(&self) -> LinkStatus {
        self.link.status()
    }

    /// The ground stations routed to the autopilot, and what passed through them.
    pub fn stations(&self) -> Vec<crate::link::StationStatus> {
        self.link.stations()
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
        // Only a HEARTBEAT heard after the last mode command says what the autopilot made of
        // it: one sent before it still shows the mode before (and would "confirm" HOLD after a
        // quick HOLD → MANUAL → HOLD). ArduPilot sends a HEARTBEAT at once on a mode change,
        // which may come before its COMMAND_ACK; either confirms.
        if let Some(a) = status.autopilot
            && status
                .last_heartbeat
                .is_some_and(|hb| self.mode_sent.is_none_or(|sent| hb > sent))
        {
            self.mode.on_heartbeat(a.custom_mode);
        }
        self.check_refusal(now);
        if self.heard_at.is_none() && status.autopilot.is_some() {
            self.heard_at = Some(now);
        }
        let up = self.heard_recently(&status);
        if up != self.link_up {
            self.link_up = up;
            if up {
                info!(endpoint = %self.config.endpoint, "mavlink: autopilot heard");
                // Back after a loss: ArduPilot leaves a GCS failsafe in HOLD, so say again what
                // rove wants. At first contact a wish already confirmed (an ACK before the
                // first HEARTBEAT) or still pending (its resends run) is not sent again; one
                // that gave up while nobody answered is.
                let gave_up = matches!(self.mode.state(), ModeState::Failed { .. });
                if self.heard_before || gave_up {
                    self.mode.reassert(now);
                }
                self.heard_before = true;
            } else {
                warn!(
                    endpoint = %self.config.endpoint,
                    timeout = ?self.config.link_timeout,
                    "mavlink: no HEARTBEAT from the autopilot"
                );
            }
        }
    }

    /// A driven mode that failed: report it once and, with `on_mode_refused = "hold"`, stop
    /// driving. A refusal ends when the autopilot reports the mode after all (HEARTBEAT).
    fn check_refusal(&mut self, now: MonoTime) {
        if let Some((mode, _)) = &self.refused
            && let Some(a) = self.link.status().autopilot
            && a.custom_mode == mode.custom_mode
        {
            info!(mode = %mode.name, "mavlink: the autopilot is in the refused mode after all");
            self.refused = None;
        }
        let ModeState::Failed { mode, reason } = self.mode.state() else {
            return;
        };
        if *mode == self.config.modes.safe
            || !matches!(self.drive, Drive::Driving(_))
            || self.refused.as_ref().is_some_and(|(m, _)| m == mode)
        {
            return;
        }
        let (mode, reason) = (mode.clone(), reason.clone());
        let hold = self.config.on_mode_refused == OnModeRefused::Hold;
        warn!(
            mode = %mode.name,
            reason = %reason,
            on_mode_refused = if hold { "hold" } else { "continue" },
            "mavlink: the autopilot did not take the operator's mode{}",
            if hold { "; stopping: failsafe and the safe mode until the operator's mode changes" } else { "; driving on in its current mode" }
        );
        self.refused = Some((mode, reason));
        if hold {
            self.enter_safe(now);
        }
    }

    /// Whether commands for `wished` are held back by a refusal.
    fn held_by_refusal(&self, wished: &AutopilotMode) -> bool {
        self.config.on_mode_refused == OnModeRefused::Hold
            && self.refused.as_ref().is_some_and(|(m, _)| m == wished)
    }

    /// Driving → safe: release (or neutral) and, if modes are ours, the safe mode.
    fn enter_safe(&mut self, now: MonoTime) {
        if matches!(self.drive, Drive::Driving(_)) {
            self.drive = Drive::Safe {
                releases_left: RELEASE_SENDS,
            };
            self.deferred = false;
            if self.config.modes.set_mode {
                self.mode.request(now, &self.config.modes.safe);
            }
        }
    }

    fn now_from_clock(&self) -> MonoTime {
        self.clock.0 + self.clock.1.elapsed()
    }
}

impl OutputAdapter for MavlinkVehicle {
    /// Who drives, for the ground stations' CONTROL_STATUS.
    fn status(
        &mut self,
        _now: MonoTime,
        status: &rove_core::msg::VehicleStatus,
    ) -> Result<(), LinkError> {
        self.link.set_owner(status.vehicle_id, status.controller_id);
        Ok(())
    }

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
        if self.link.target().is_none() {
            // Nobody to address yet (the autopilot's first HEARTBEAT): routine at start, and
            // holding the outputs would only delay the first override once it is heard. Not
            // driving either, so the safe state that follows commands no safe mode.
            if !self.warned_unheard {
                self.warned_unheard = true;
                warn!(
                    endpoint = %self.config.endpoint,
                    "mavlink: commands arrive but no autopilot heard yet; they start when it is"
                );
            }
            return Err(LinkError {
                disposition: Disposition::Silent,
                detail: format!("mavlink {}: no autopilot heard yet", self.config.endpoint),
            });
        }
        if self.config.modes.set_mode {
            let wished = self.config.modes.for_mode(setpoint.mode).clone();
            if self.held_by_refusal(&wished) {
                // Refused and on_mode_refused = "hold": stay safe until the operator's mode
                // changes; the failsafe content goes out at the keep-alive rate.
                return self.keepalive(now);
            }
            if self.refused.as_ref().is_some_and(|(m, _)| *m != wished) {
                self.refused = None;
            }
            self.mode.request(now, &wished);
        }
        self.drive = Drive::Driving(*setpoint);
        self.fresh = false;
        // The control message first: it is what the latency budget is about.
        let control = if self.budget_allows(now) {
            self.send_sticks(now, &setpoint.movement)
        } else {
            self.deferred = true;
            Ok(())
        };
        let mode = self.send_mode_if_due(now);
        let protocol = self.ask_for_control_if_due().and(self.answer_forwarded());
        let heartbeat = self.send_heartbeat_if_due(now).and(protocol);
        first_error([control, mode, heartbeat]).map_err(|e| self.connecting(e))
    }

    fn safe_state(&mut self, now: MonoTime) -> Result<(), LinkError> {
        self.clock = (now, Instant::now());
        self.observe(now);
        self.enter_safe(now);
        let control = match self.link.target() {
            // Nothing to release on an autopilot never heard.
            None => Ok(()),
            Some(_) => self.send_failsafe(now),
        };
        let mode = self.send_mode_if_due(now);
        let forwarded = self.answer_forwarded();
        let heartbeat = self.send_heartbeat_if_due(now).and(forwarded);
        first_error([control, mode, heartbeat]).map_err(|e| self.connecting(e))
    }

    fn keepalive_period(&self) -> Option<Duration> {
        Some(self.period)
    }

    fn keepalive(&mut self, now: MonoTime) -> Result<(), LinkError> {
        self.clock = (now, Instant::now());
        self.observe(now);
        let protocol = match self.drive {
            Drive::Driving(_) => self.ask_for_control_if_due(),
            Drive::Safe { .. } => Ok(()),
        };
        let heartbeat = (self.send_heartbeat_if_due(now))
            .and(protocol)
            .and(self.answer_forwarded());
        let due = self.keepalive_due(now) || (self.deferred && self.budget_allows(now));
        let control = match self.drive {
            Drive::Driving(setpoint) if due => self.send_sticks(now, &setpoint.movement),
            Drive::Safe { .. } if due && self.link.target().is_some() => self.send_failsafe(now),
            _ => Ok(()),
        };
        let mode = self.send_mode_if_due(now);
        first_error([heartbeat, control, mode]).map_err(|e| self.connecting(e))
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
        if let Some((mode, reason)) = &self.refused {
            return Health::Degraded(match self.config.on_mode_refused {
                OnModeRefused::Hold => format!(
                    "{reason}; holding in {} until the operator's mode changes",
                    self.config.modes.safe.name
                ),
                OnModeRefused::Continue => format!("{reason}; driving on without {}", mode.name),
            });
        }
        if let (Drive::Driving(_), crate::control::Standing::Waiting { gcs_main }) =
            (self.drive, self.standing())
        {
            let holder = match gcs_main {
                0 => "nobody is in control of the autopilot".to_string(),
                id => format!("system {id} is in control of the autopilot"),
            };
            return Health::Degraded(format!(
                "{holder} (its system manager says so); rove asked for control"
            ));
        }
        match self.mode.state() {
            ModeState::Failed { reason, .. } => Health::Degraded(reason.clone()),
            _ => Health::Ok,
        }
    }

    fn held_safe(&self) -> bool {
        self.config.on_mode_refused == OnModeRefused::Hold && self.refused.is_some()
    }

    fn telemetry(&self) -> Telemetry {
        let status = self.link.status();
        let Some(a) = status.autopilot else {
            return Telemetry::default();
        };
        Telemetry {
            battery_mv: status.battery.and_then(|b| b.mv),
            battery_pct: status.battery.and_then(|b| b.pct),
            autopilot_mode: Some(self.mode_name(a.custom_mode)),
            armed: Some(a.armed),
            link_age: status.last_heartbeat.map(|t| t.elapsed()),
        }
    }

    fn detail(&self) -> Option<String> {
        let summary = self.autopilot_summary();
        Some(match &self.refused {
            Some((mode, _)) => format!("{summary}; {} refused", mode.name),
            None => summary,
        })
    }
}

impl MavlinkVehicle {
    /// The autopilot's name for `custom_mode` (`"HOLD"`), or `"mode N"` if it is not in the
    /// table for this autopilot and vehicle.
    fn mode_name(&self, custom_mode: u32) -> String {
        crate::config::mode_table(self.config.autopilot, self.config.vehicle)
            .into_iter()
            .find(|&(_, m)| m == custom_mode)
            .map_or_else(|| format!("mode {custom_mode}"), |(n, _)| n.to_string())
    }

    /// A line for status displays: the autopilot, its mode and armed state.
    pub fn autopilot_summary(&self) -> String {
        let status = self.link.status();
        match status.autopilot {
            None => "no autopilot heard".into(),
            Some(a) => {
                let mode = self.mode_name(a.custom_mode);
                format!(
                    "system {} ({:?}), {mode}, {}",
                    a.system_id,
                    self.config.autopilot,
                    if a.armed { "armed" } else { "disarmed" }
                )
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::stop::confirmation;
    use super::*;

    /// Issue 50: an ACK-only run said "no autopilot heard" while HOLD was acknowledged.
    #[test]
    fn the_failsafe_summary_names_who_confirmed_the_safe_mode_and_how() {
        let hold = AutopilotMode {
            name: "HOLD".into(),
            custom_mode: 4,
        };
        let name = |m: u32| format!("mode {m}");
        let mut status = LinkStatus {
            acked_by: Some((1, 1)),
            ..LinkStatus::default()
        };
        assert_eq!(
            confirmation(&status, &hold, name),
            "system 1/1 acknowledged HOLD (COMMAND_ACK; no HEARTBEAT heard yet)"
        );
        let mut heard = crate::link::AutopilotInfo {
            system_id: 1,
            component_id: 1,
            mav_type: 10,
            autopilot: 3,
            custom_mode: 0,
            armed: true,
        };
        status.autopilot = Some(heard);
        assert_eq!(
            confirmation(&status, &hold, name),
            "system 1/1 acknowledged HOLD (its last HEARTBEAT, older, said mode 0), armed"
        );
        heard.custom_mode = 4;
        status.autopilot = Some(heard);
        assert_eq!(
            confirmation(&status, &hold, name),
            "system 1/1 in HOLD, armed"
        );
        for summary in [
            confirmation(&status, &hold, name),
            confirmation(&LinkStatus::default(), &hold, name),
        ] {
            assert!(!summary.contains("no autopilot heard"), "{summary}");
        }
    }

    #[test]
    fn serial_budget_lowers_the_rate_only_on_slow_links() {
        // RC_CHANNELS_OVERRIDE, MAVLink 2: 38-byte payload + 12 = 50 bytes.
        let mut settings: crate::MavlinkSettings = toml::from_str("").expect("parses");
        let config = settings.validate().expect("valid");
        assert_eq!(control_frame_bytes(&config), 50);
        // 57 600 baud: 5 760 B/s, half of it 2 880 B/s → 50 B every 17.4 ms (57 Hz): 25 Hz fits.
        let gap = serial_min_gap(57_600, 50, SERIAL_SHARE);
        assert!((17..=18).contains(&gap.as_millis()), "{gap:?}");
        assert!(gap < config.period);
        // 9 600 baud: 480 B/s → 104 ms (9.6 Hz): 25 Hz must be lowered.
        let gap = serial_min_gap(9_600, 50, SERIAL_SHARE);
        assert_eq!(gap.as_millis(), 104);
        assert_eq!(serial_min_gap(0, 50, SERIAL_SHARE), Duration::from_secs(1));
    }
}
