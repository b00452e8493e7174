//! The CAN vehicle: a [`CanConfig`]'s raw frames and DroneCAN commands on one [`CanBus`], as
//! an [`OutputAdapter`].
//!
//! # Sending
//! Every frame (and each DroneCAN command message) is sent when its bytes change and otherwise
//! at its configured rate: [`OutputAdapter::apply`] sends what changed at once,
//! [`OutputAdapter::keepalive`] re-sends whatever is due. A frame counts as due half a
//! keep-alive period early, so the gateway's timer jitter never stretches a gap to two periods.
//! NodeStatus goes out once a second while DroneCAN is configured.
//!
//! # Safe state
//! Written (all frames, at once) before [`CanVehicle::new`] returns, on
//! [`OutputAdapter::safe_state`] and from `Drop`; the keep-alive then repeats it at rate, since
//! CAN devices time out as well. In the safe state each output sends its `failsafe` value.
//!
//! # Failures and recovery
//! A failed send, or a bus-off report, puts the vehicle down: outputs fall back to the safe
//! state, health is [`Health::Down`] and every call returns the (transient) error until the
//! link is back. Every [`REOPEN_INTERVAL`] a call retries: after bus-off it waits for the
//! controller to restart; after a failed send it reopens the interface by name (an unplugged
//! adapter comes back with a new interface index). Once up again the safe state is sent until
//! the next [`OutputAdapter::apply`]: a recovered bus never resumes an old command on its own.

use crate::bus::{BusState, CanBus, CanFrameData};
use crate::config::CanConfig;
use crate::dronecan::{
    self, ARRAY_COMMAND, DataType, NODE_STATUS, NODE_STATUS_PRIORITY, NodeHealth, RAW_COMMAND,
    TransferIds,
};
use crate::protocol;
use rove_core::MonoTime;
use rove_core::adapter::{Health, OutputAdapter};
use rove_core::arbiter::Setpoint;
use rove_core::error::LinkError;
use rove_core::msg::MovementCommand;
use std::time::Duration;

/// How often a down link is retried (bus state checked, interface reopened). 100 ms notices a
/// replugged adapter or a restarted controller quickly; each retry is a few system calls, so a
/// shorter interval only spends CPU while the bus is gone.
pub const REOPEN_INTERVAL: Duration = Duration::from_millis(100);

/// What the outputs follow.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Drive {
    /// Every output at its failsafe value.
    Failsafe,
    /// The last applied movement.
    Moving(MovementCommand),
}

impl Drive {
    fn movement(&self) -> Option<&MovementCommand> {
        match self {
            Drive::Failsafe => None,
            Drive::Moving(m) => Some(m),
        }
    }
}

/// One periodically sent message: what went out last and when it is due again.
#[derive(Debug, Clone, Default)]
struct Slot {
    last: Option<Vec<u8>>,
    next_due: MonoTime,
}

impl Slot {
    /// Whether `bytes` must go out now.
    fn wants(&self, now: MonoTime, early: Duration, bytes: &[u8], force: bool) -> bool {
        force || self.last.as_deref() != Some(bytes) || now + early >= self.next_due
    }

    fn sent(&mut self, now: MonoTime, period: Duration, bytes: Vec<u8>) {
        self.last = Some(bytes);
        self.next_due = now + period;
    }
}

/// Why the link is down, and when to retry.
#[derive(Debug, Clone)]
struct Down {
    error: LinkError,
    retry_at: MonoTime,
    /// The socket may be dead (a send failed): reopen it before trusting it again.
    reopen: bool,
}

/// A CAN vehicle on a boxed bus.
pub struct CanVehicle {
    config: CanConfig,
    bus: Box<dyn CanBus + Send>,
    drive: Drive,
    raw: Vec<Slot>,
    servos: Slot,
    escs: Slot,
    status: Slot,
    transfer_ids: TransferIds,
    started: MonoTime,
    down: Option<Down>,
    degraded: Option<String>,
    /// The latest `now` seen, for the safe-state write in `Drop` (which gets no time).
    last_now: MonoTime,
}

impl std::fmt::Debug for CanVehicle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CanVehicle")
            .field("bus", &self.bus.describe())
            .field("drive", &self.drive)
            .field("down", &self.down)
            .field("degraded", &self.degraded)
            .finish_non_exhaustive()
    }
}

impl CanVehicle {
    /// Sends the safe state on `bus`, then returns the vehicle.
    ///
    /// # Errors
    /// The [`LinkError`] of the first frame that could not be sent (or a bus-off report); the
    /// bus is dropped, open a new one to retry.
    pub fn new(
        config: CanConfig,
        bus: Box<dyn CanBus + Send>,
        now: MonoTime,
    ) -> Result<CanVehicle, LinkError> {
        let mut vehicle = CanVehicle {
            raw: vec![Slot::default(); config.frames().len()],
            config,
            bus,
            drive: Drive::Failsafe,
            servos: Slot::default(),
            escs: Slot::default(),
            status: Slot::default(),
            transfer_ids: TransferIds::default(),
            started: now,
            down: None,
            degraded: None,
            last_now: now,
        };
        vehicle.safe_state(now)?;
        Ok(vehicle)
    }

    /// The validated config.
    pub fn config(&self) -> &CanConfig {
        &self.config
    }

    /// Whether the outputs are in the safe state (after `safe_state`, a failure or recovery).
    pub fn in_failsafe(&self) -> bool {
        self.drive == Drive::Failsafe
    }

    fn early(&self) -> Duration {
        self.config.keepalive_period() / 2
    }

    fn fail(&mut self, now: MonoTime, error: LinkError, reopen: bool) -> LinkError {
        self.drive = Drive::Failsafe;
        self.down = Some(Down {
            error: error.clone(),
            retry_at: now + REOPEN_INTERVAL,
            reopen,
        });
        error
    }

    fn bus_off_error(&self) -> LinkError {
        LinkError::transient(format!(
            "{}: bus-off (too many bus errors: check wiring, termination and bitrate; the \
             controller restarts by itself only with `restart-ms` set)",
            self.bus.describe()
        ))
    }

    /// Brings a down link back if it is time to retry; `Ok(true)` if it just came back.
    fn check_link(&mut self, now: MonoTime) -> Result<bool, LinkError> {
        let Some(down) = self.down.clone() else {
            return Ok(false);
        };
        if now < down.retry_at {
            return Err(down.error);
        }
        match self.bus.state() {
            Ok(BusState::BusOff) => {
                let e = self.bus_off_error();
                return Err(self.fail(now, e, down.reopen));
            }
            Err(e) => return Err(self.fail(now, e, true)),
            Ok(_) => {}
        }
        if down.reopen
            && let Err(e) = self.bus.reopen()
        {
            return Err(self.fail(now, e, true));
        }
        self.down = None;
        self.drive = Drive::Failsafe;
        // Nothing sent before the failure counts: everything goes out again.
        for slot in self.raw.iter_mut().chain([&mut self.servos, &mut self.escs]) {
            *slot = Slot::default();
        }
        Ok(true)
    }

    /// Sends what is due (everything if `force`).
    fn cycle(&mut self, now: MonoTime, force: bool) -> Result<(), LinkError> {
        self.last_now = self.last_now.max(now);
        let force = self.check_link(now)? || force;
        match self.bus.state() {
            Ok(BusState::BusOff) => {
                let e = self.bus_off_error();
                return Err(self.fail(now, e, false));
            }
            Ok(BusState::Degraded(why)) => self.degraded = Some(why),
            Ok(BusState::Active) => self.degraded = None,
            Err(e) => return Err(self.fail(now, e, true)),
        }
        match self.send_due(now, force) {
            Ok(()) => Ok(()),
            Err(e) => Err(self.fail(now, e, true)),
        }
    }

    fn send_due(&mut self, now: MonoTime, force: bool) -> Result<(), LinkError> {
        let early = self.early();
        let movement = self.drive.movement().copied();
        let movement = movement.as_ref();
        let interface = self.config.interface().to_string();
        let frame_error = |e: crate::FrameError| LinkError::fatal(format!("{interface}: {e}"));
        for (frame_config, slot) in self.config.frames().iter().zip(self.raw.iter_mut()) {
            let frame = protocol::raw_frame(frame_config, movement).map_err(frame_error)?;
            if slot.wants(now, early, frame.data(), force) {
                self.bus.send(now, &frame)?;
                slot.sent(now, frame_config.period(), frame.data().to_vec());
            }
        }
        let Some(dc) = self.config.dronecan() else {
            return Ok(());
        };
        let (node, priority, period) = (dc.node_id(), dc.priority(), dc.period());
        let mut transfers: Vec<(DataType, u8, Vec<u8>, &mut Slot, Duration)> = Vec::new();
        if !dc.servos().is_empty() {
            let payload = dronecan::array_command(&protocol::servo_commands(dc, movement));
            transfers.push((ARRAY_COMMAND, priority, payload, &mut self.servos, period));
        }
        if !dc.escs().is_empty() {
            let payload = dronecan::raw_command(&protocol::esc_commands(dc, movement));
            transfers.push((RAW_COMMAND, priority, payload, &mut self.escs, period));
        }
        if now + early >= self.status.next_due {
            let uptime = now.saturating_since(self.started).as_secs();
            let health = if movement.is_some() {
                NodeHealth::Ok
            } else {
                NodeHealth::Warning
            };
            let payload =
                dronecan::node_status(u32::try_from(uptime).unwrap_or(u32::MAX), health, 0);
            transfers.push((
                NODE_STATUS,
                NODE_STATUS_PRIORITY,
                payload,
                &mut self.status,
                crate::config::NODE_STATUS_PERIOD,
            ));
        }
        for (data_type, priority, payload, slot, period) in transfers {
            // NodeStatus changes every second (uptime): it goes by its period only.
            let wanted = if data_type == NODE_STATUS {
                true
            } else {
                slot.wants(now, early, &payload, force)
            };
            if !wanted {
                continue;
            }
            let tid = self.transfer_ids.next(&data_type);
            let frames: Vec<CanFrameData> =
                dronecan::transfer_frames(&data_type, priority, node, tid, &payload)
                    .map_err(frame_error)?;
            for frame in &frames {
                self.bus.send(now, frame)?;
            }
            slot.sent(now, period, payload);
        }
        Ok(())
    }
}

impl OutputAdapter for CanVehicle {
    fn describe(&self) -> String {
        let names = self.config.output_names().join(", ");
        let dronecan = self
            .config
            .dronecan()
            .map(|d| format!(", DroneCAN node {}", d.node_id()))
            .unwrap_or_default();
        format!(
            "can vehicle [{names}] on {}{dronecan}",
            self.bus.describe()
        )
    }

    fn apply(&mut self, now: MonoTime, setpoint: &Setpoint) -> Result<(), LinkError> {
        self.check_link(now)?;
        self.drive = Drive::Moving(setpoint.movement);
        self.cycle(now, false)
    }

    fn safe_state(&mut self, now: MonoTime) -> Result<(), LinkError> {
        self.drive = Drive::Failsafe;
        self.cycle(now, true)
    }

    fn keepalive_period(&self) -> Option<Duration> {
        Some(self.config.keepalive_period())
    }

    fn keepalive(&mut self, now: MonoTime) -> Result<(), LinkError> {
        self.cycle(now, false)
    }

    fn health(&self) -> Health {
        match (&self.down, &self.degraded) {
            (Some(down), _) => Health::Down(down.error.detail.clone()),
            (None, Some(why)) => Health::Degraded(why.clone()),
            (None, None) => Health::Ok,
        }
    }
}

impl Drop for CanVehicle {
    fn drop(&mut self) {
        // One last safe-state frame set, so a device that holds its last value holds the safe
        // one. Errors have nowhere to go from here; a down link is skipped by `cycle`.
        let now = self.last_now;
        let _ = self.safe_state(now);
    }
}
