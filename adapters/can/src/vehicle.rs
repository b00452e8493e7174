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
            raw: vec![Slot::default(); config.frames.len()],
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
        for slot in self
            .raw
            .iter_mut()
            .chain([&mut self.servos, &mut self.escs])
        {
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
        let interface = self.config.interface.to_string();
        let frame_error = |e: crate::FrameError| LinkError::fatal(format!("{interface}: {e}"));
        for (frame_config, slot) in self.config.frames.iter().zip(self.raw.iter_mut()) {
            let frame = protocol::raw_frame(frame_config, movement).map_err(frame_error)?;
            if slot.wants(now, early, frame.data(), force) {
                self.bus.send(now, &frame)?;
                slot.sent(now, frame_config.period, frame.data().to_vec());
            }
        }
        let Some(dc) = self.config.dronecan.as_ref() else {
            return Ok(());
        };
        let (node, priority, period) = (dc.node_id, dc.priority, dc.period);
        let mut transfers: Vec<(DataType, u8, Vec<u8>, &mut Slot, Duration)> = Vec::new();
        if !dc.servos.is_empty() {
            let payload = dronecan::array_command(&protocol::servo_commands(dc, movement));
            transfers.push((ARRAY_COMMAND, priority, payload, &mut self.servos, period));
        }
        if !dc.escs.is_empty() {
            let payload = dronecan::raw_command(&protocol::esc_commands(dc, movement));
            transfers.push((RAW_COMMAND, priority, payload, &mut self.escs, period));
        }
        if now + early >= self.status.next_due {
            // Rounded to the nearest second, as pydronecan's node does.
            let uptime =
                (now.saturating_since(self.started) + Duration::from_millis(500)).as_secs();
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
            .dronecan
            .as_ref()
            .map(|d| format!(", DroneCAN node {}", d.node_id))
            .unwrap_or_default();
        format!("can vehicle [{names}] on {}{dronecan}", self.bus.describe())
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bus::{FakeBus, FakeBusHandle, FakeFault, SentFrame, errno};
    use crate::config::CanSettings;
    use rove_core::error::Disposition;
    use rove_core::msg::Mode;

    /// Two motors on one frame (0x201, 20 ms) and a light on a slow frame (0x300, 100 ms).
    const SKID: &str = r#"
        interface = "can0"
        [[frames]]
        id = 0x201
        [[frames.outputs]]
        name = "left"
        source = { mix = [["throttle", 1.0], ["roll", 1.0]] }
        offset = 0
        min = -1000
        max = 1000
        [[frames.outputs]]
        name = "right"
        source = { mix = [["throttle", 1.0], ["roll", -1.0]] }
        offset = 2
        min = -1000
        max = 1000
        failsafe = 7
        [[frames]]
        id = 0x300
        rate_hz = 10
        [[frames.outputs]]
        name = "beacon"
        source = "yaw"
        offset = 0
        width = 8
        signed = false
    "#;

    const DRONECAN: &str = r#"
        interface = "can0"
        rate_hz = 50
        [dronecan]
        node_id = 100
        [[dronecan.servos]]
        actuator_id = 0
        source = "roll"
        [[dronecan.servos]]
        actuator_id = 1
        source = "pitch"
        failsafe = 0.5
        [[dronecan.escs]]
        index = 0
        source = "throttle"
    "#;

    fn vehicle(text: &str) -> (CanVehicle, FakeBusHandle) {
        let config = toml::from_str::<CanSettings>(text)
            .expect("parses")
            .validate()
            .expect("valid");
        let (bus, handle) = FakeBus::new("fake0", false);
        let v = CanVehicle::new(config, Box::new(bus), MonoTime::ZERO).expect("starts");
        (v, handle)
    }

    fn ms(t: u64) -> MonoTime {
        MonoTime::from_millis(t)
    }

    fn sp(throttle: i16, roll: i16) -> Setpoint {
        Setpoint {
            movement: MovementCommand {
                throttle,
                roll,
                ..MovementCommand::CENTRED
            },
            mode: Mode::Manual,
        }
    }

    /// `(ms, id, bytes)` of each frame.
    fn summary(frames: &[SentFrame]) -> Vec<(u64, u32, Vec<u8>)> {
        frames
            .iter()
            .map(|s| {
                (
                    s.at.as_nanos() / 1_000_000,
                    s.frame.id().raw(),
                    s.frame.data().to_vec(),
                )
            })
            .collect()
    }

    #[test]
    fn new_sends_the_safe_state() {
        let (v, bus) = vehicle(SKID);
        assert!(v.in_failsafe());
        // left centre 0, right failsafe 7; beacon centre 127.
        assert_eq!(
            summary(&bus.take()),
            [(0, 0x201, vec![0, 0, 7, 0]), (0, 0x300, vec![127])]
        );
        assert_eq!(v.keepalive_period(), Some(Duration::from_millis(20)));
        assert_eq!(v.health(), Health::Ok);
        assert_eq!(
            v.describe(),
            "can vehicle [left, right, beacon] on fake CAN bus fake0"
        );
    }

    #[test]
    fn apply_mixes_skid_steer_and_sends_changes_at_once() {
        let (mut v, bus) = vehicle(SKID);
        bus.take();
        // Half throttle, quarter right: left 750, right 250.
        v.apply(ms(5), &sp(16384, 8192)).expect("sent");
        assert_eq!(
            summary(&bus.take()),
            [(5, 0x201, vec![0xEE, 0x02, 0xFA, 0x00])]
        );
        // The same values again: nothing new until due.
        v.apply(ms(10), &sp(16384, 8192)).expect("ok");
        assert!(bus.take().is_empty());
        // Full throttle, full right: left clamps to 1000, right 0.
        v.apply(ms(12), &sp(i16::MAX, i16::MAX)).expect("sent");
        assert_eq!(
            summary(&bus.take()),
            [(12, 0x201, vec![0xE8, 0x03, 0x00, 0x00])]
        );
        assert!(!v.in_failsafe());
    }

    #[test]
    fn keepalive_repeats_each_frame_at_its_rate_driving_and_in_failsafe() {
        let (mut v, bus) = vehicle(SKID);
        v.apply(ms(0), &sp(1000, 0)).expect("sent");
        bus.take();
        // The gateway calls keepalive every 20 ms (with a little jitter).
        for i in 1..=10u64 {
            v.keepalive(ms(20 * i - (i % 2))).expect("sent");
        }
        let sent = summary(&bus.take());
        let fast = sent.iter().filter(|f| f.1 == 0x201).count();
        let slow = sent.iter().filter(|f| f.1 == 0x300).count();
        assert_eq!((fast, slow), (10, 2), "{sent:?}");
        assert!(sent.iter().all(|f| f.1 != 0x201 || f.2 == [31, 0, 31, 0]));
        v.safe_state(ms(200)).expect("sent");
        assert_eq!(
            summary(&bus.take()),
            [(200, 0x201, vec![0, 0, 7, 0]), (200, 0x300, vec![127])]
        );
        for i in 1..=5u64 {
            v.keepalive(ms(200 + 20 * i)).expect("sent");
        }
        let sent = summary(&bus.take());
        assert_eq!(sent.iter().filter(|f| f.1 == 0x201).count(), 5);
        assert!(sent.iter().all(|f| f.1 != 0x201 || f.2 == [0, 0, 7, 0]));
        // 0x300 last went out at 200 ms: once more at 300 ms.
        assert_eq!(
            sent.iter()
                .filter(|f| f.1 == 0x300)
                .map(|f| f.0)
                .collect::<Vec<_>>(),
            [300]
        );
    }

    #[test]
    fn bus_off_goes_down_in_failsafe_and_recovers_without_restart() {
        let (mut v, bus) = vehicle(SKID);
        v.apply(ms(0), &sp(16384, 0)).expect("sent");
        bus.take();
        bus.fail(FakeFault::BusOff);
        let err = v.keepalive(ms(20)).expect_err("bus-off");
        assert_eq!(err.disposition, Disposition::Transient);
        assert!(err.detail.contains("bus-off"), "{}", err.detail);
        assert!(matches!(v.health(), Health::Down(d) if d.contains("bus-off")));
        assert!(v.in_failsafe());
        // Still down, and still an error, before and after the retry while bus-off.
        assert!(v.keepalive(ms(40)).is_err());
        assert!(v.apply(ms(50), &sp(16384, 0)).is_err());
        assert!(v.keepalive(ms(130)).is_err());
        assert!(bus.take().is_empty());
        // The controller restarts: at the next retry the safe state goes out, not the old
        // command, and the bus needed no reopen.
        bus.heal();
        assert!(v.keepalive(ms(200)).is_err(), "retry not due until 230 ms");
        v.keepalive(ms(240)).expect("back");
        assert_eq!(v.health(), Health::Ok);
        assert_eq!(
            summary(&bus.take()),
            [(240, 0x201, vec![0, 0, 7, 0]), (240, 0x300, vec![127])]
        );
        assert_eq!(bus.reopens(), 0);
        v.apply(ms(250), &sp(16384, 0)).expect("drives again");
        assert_eq!(
            summary(&bus.take()),
            [(250, 0x201, vec![0xF4, 0x01, 0xF4, 0x01])]
        );
    }

    #[test]
    fn interface_loss_reopens_by_name_once_it_is_back() {
        let (mut v, bus) = vehicle(SKID);
        bus.take();
        bus.fail(FakeFault::InterfaceGone);
        let err = v.keepalive(ms(20)).expect_err("down");
        assert_eq!(
            err,
            LinkError::transient("fake0: send: interface down (errno 100)")
        );
        // Reopen fails while the interface is gone; the error says so.
        let err = v.keepalive(ms(120)).expect_err("still gone");
        assert_eq!(err.detail, "fake0: open: no such interface (errno 19)");
        assert_eq!(v.health(), Health::Down(err.detail.clone()));
        bus.heal();
        v.safe_state(ms(220)).expect("reopened");
        assert_eq!(bus.reopens(), 1);
        assert_eq!(v.health(), Health::Ok);
        assert_eq!(summary(&bus.take()).len(), 2);
    }

    #[test]
    fn a_fatal_errno_is_reported_fatal() {
        let (mut v, bus) = vehicle(SKID);
        bus.fail(FakeFault::Errno(errno::EPERM));
        let err = v.apply(ms(1), &sp(0, 0)).expect_err("refused");
        assert_eq!(err.disposition, Disposition::Fatal);
        assert!(matches!(v.health(), Health::Down(_)));
    }

    #[test]
    fn degraded_bus_still_sends_and_says_why() {
        let (mut v, bus) = vehicle(SKID);
        bus.take();
        bus.set_degraded(Some("ERROR PASSIVE (transmit)"));
        v.apply(ms(1), &sp(100, 0)).expect("sent");
        assert_eq!(
            v.health(),
            Health::Degraded("ERROR PASSIVE (transmit)".into())
        );
        assert_eq!(bus.take().len(), 1);
        bus.set_degraded(None);
        v.keepalive(ms(21)).expect("sent");
        assert_eq!(v.health(), Health::Ok);
    }

    #[test]
    fn a_failing_start_is_an_error() {
        let config = toml::from_str::<CanSettings>(SKID)
            .expect("parses")
            .validate()
            .expect("valid");
        let (bus, handle) = FakeBus::new("fake0", false);
        handle.fail(FakeFault::InterfaceGone);
        let err = CanVehicle::new(config, Box::new(bus), MonoTime::ZERO).expect_err("down");
        assert_eq!(err.disposition, Disposition::Transient);
    }

    #[test]
    fn drop_sends_the_safe_state_at_the_last_time_seen() {
        let (mut v, bus) = vehicle(SKID);
        v.apply(ms(500), &sp(i16::MAX, 0)).expect("sent");
        bus.take();
        drop(v);
        assert_eq!(
            summary(&bus.take()),
            [(500, 0x201, vec![0, 0, 7, 0]), (500, 0x300, vec![127])]
        );
    }

    #[test]
    fn dronecan_commands_heartbeat_and_transfer_ids() {
        let (mut v, bus) = vehicle(DRONECAN);
        let start = bus.take();
        // Safe state at start: ArrayCommand (2 servos, 8 bytes → 2 frames), RawCommand (one
        // ESC, 1 frame), NodeStatus (1 frame).
        let ids: Vec<u32> = start.iter().map(|s| s.frame.id().raw()).collect();
        assert_eq!(ids, [0x1003_F264, 0x1003_F264, 0x1004_0664, 0x1801_5564]);
        // ArrayCommand payload [0, 0, 0.0, 1, 0, 0.5]: CRC first, transfer id 0.
        assert_eq!(start[0].frame.data()[2..7], [0x00, 0x00, 0x00, 0x00, 0x01]);
        assert_eq!(start[0].frame.data()[7], 0x80);
        assert_eq!(start[1].frame.data(), [0x00, 0x00, 0x38, 0x60]);
        // RawCommand: ESC failsafe 0.
        assert_eq!(start[2].frame.data(), [0x00, 0x00, 0xC0]);
        // NodeStatus in failsafe: uptime 0, health WARNING.
        assert_eq!(start[3].frame.data(), [0, 0, 0, 0, 0x40, 0, 0, 0xC0]);
        // Driving: full throttle → ESC 8191; servos roll −1 → −1.0.
        v.apply(ms(10), &sp(i16::MAX, -i16::MAX)).expect("sent");
        let sent = bus.take();
        assert_eq!(sent.len(), 3);
        // Transfer id 1 now (tail of the last ArrayCommand frame: end, toggle, tid 1).
        assert_eq!(sent[1].frame.data().last(), Some(&0x61));
        assert_eq!(sent[2].frame.data(), [0xFF, 0x7C, 0xC1]);
        // Keep-alives for 2 s at 50 Hz: commands every 20 ms, NodeStatus once a second.
        for i in 1..=100u64 {
            v.keepalive(ms(10 + 20 * i)).expect("sent");
        }
        let sent = bus.take();
        let status: Vec<&SentFrame> = sent
            .iter()
            .filter(|s| s.frame.id().raw() == 0x1801_5564)
            .collect();
        let at: Vec<u64> = status.iter().map(|s| s.at.as_nanos() / 1_000_000).collect();
        // Due at 1000 ms; half a keep-alive period early counts.
        assert_eq!(at, [990, 1990]);
        // Uptime 1 s then 2 s, health OK while driving; transfer ids 1, 2.
        assert_eq!(status[0].frame.data(), [1, 0, 0, 0, 0, 0, 0, 0xC1]);
        assert_eq!(status[1].frame.data(), [2, 0, 0, 0, 0, 0, 0, 0xC2]);
        let esc = sent
            .iter()
            .filter(|s| s.frame.id().raw() == 0x1004_0664)
            .count();
        assert_eq!(esc, 100);
    }
}
