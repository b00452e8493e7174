//! What the vehicle tells about itself: VehicleStatus on DDS, the `STATUS=` line for systemd,
//! and the watches that annotate it (an output hung past its limit, messages not believed).

use crate::output::OutputReport;

use rove_core::arbiter::{Arbiter, Owner, ParticipantId};
use rove_core::msg::{DeviceId, VehicleStatus};
use rove_core::trust::Suspect;
use std::collections::HashMap;
use std::time::Duration;
use tracing::{info, warn};

/// The vehicle's VehicleStatus as last published: a new one is published when it changes
/// (checked on every owner change and every heartbeat).
pub(super) struct StatusWatch {
    me: DeviceId,
    /// The mode last applied.
    pub(super) mode: rove_core::msg::Mode,
    /// `[vehicle] battery_low_pct`.
    battery_low_pct: u8,
    last: Option<VehicleStatus>,
    /// When `last` was published.
    last_at: rove_core::MonoTime,
}

/// Health-only changes (a battery that drains, a link age that grows) are published at most
/// this often; anything else at once.
pub(super) const HEALTH_PERIOD: Duration = Duration::from_secs(1);

impl StatusWatch {
    pub(super) fn new(me: DeviceId, battery_low_pct: u8) -> StatusWatch {
        StatusWatch {
            me,
            mode: rove_core::msg::Mode::Manual,
            battery_low_pct,
            last: None,
            last_at: rove_core::MonoTime::ZERO,
        }
    }

    /// The status to publish at `now`, if it changed: at once when more than its health
    /// changed, else at most once per [`HEALTH_PERIOD`].
    pub(super) fn changed(
        &mut self,
        arbiter: &Arbiter,
        report: &OutputReport,
        now: rove_core::MonoTime,
    ) -> Option<&VehicleStatus> {
        let mut status = vehicle_status(self.me, arbiter, self.mode, report);
        let pct = status.health.battery_pct;
        status.health.battery_low = (0..=i16::from(self.battery_low_pct)).contains(&pct);
        if let Some(last) = &self.last {
            let health_only = VehicleStatus {
                health: status.health.clone(),
                ..last.clone()
            } == status;
            let recent = now.saturating_since(self.last_at) < HEALTH_PERIOD;
            if *last == status || (health_only && recent) {
                return None;
            }
        }
        self.last = Some(status);
        self.last_at = now;
        self.last.as_ref()
    }
}

/// What VehicleStatus says: the owner, the mode last applied, whether the outputs are safe
/// (the failsafe owns them, the output is down, or the adapter holds them safe itself: an
/// autopilot that refused the owner's mode; issue 30), the output's health, and what its
/// device says of the vehicle (battery, autopilot; `battery_low` is the caller's to judge).
pub(super) fn vehicle_status(
    me: DeviceId,
    arbiter: &Arbiter,
    mode: rove_core::msg::Mode,
    report: &OutputReport,
) -> VehicleStatus {
    use rove_core::adapter::Health;
    use rove_core::msg::OutputState;
    let output = match (&report.hung, &report.health) {
        (Some(_), _) => OutputState::Hung,
        (None, Health::Ok) => OutputState::Ok,
        (None, Health::Degraded(_)) => OutputState::Degraded,
        (None, Health::Down(_)) => OutputState::Down,
    };
    VehicleStatus {
        vehicle_id: me,
        controller_id: arbiter.controller_id(),
        mode,
        failsafe: arbiter.owner() == Owner::Failsafe
            || output == OutputState::Down
            || report.held_safe,
        output,
        // Whole durations only, so that a hung call's growing age does not count as a change.
        detail: match report.hung {
            Some(hung) => format!("a device call has not returned for {} s", hung.as_secs()),
            None => report.to_string(),
        },
        health: health(report),
    }
}

/// The wire's health from the output's telemetry: unknown parts as the wire spells them.
fn health(report: &OutputReport) -> rove_core::msg::VehicleHealth {
    let t = &report.telemetry;
    rove_core::msg::VehicleHealth {
        battery_mv: (t.battery_mv).map_or(-1, |mv| i32::try_from(mv).unwrap_or(i32::MAX)),
        battery_pct: t.battery_pct.map_or(-1, |p| i16::from(p.min(100))),
        battery_low: false,
        autopilot_mode: t.autopilot_mode.clone().unwrap_or_default(),
        armed: t.armed.unwrap_or(false),
        link_age_ms: (t.link_age)
            .map_or(-1, |age| i32::try_from(age.as_millis()).unwrap_or(i32::MAX)),
        held: report.held_safe,
    }
}

/// The `STATUS=` line: who drives, how many operators are live, and the output's health.
/// E.g. `driven by 11 (2 operators live); output ok` or
/// `failsafe (no operator live); output down: …`.
pub(super) fn status_line(
    arbiter: &Arbiter,
    output: &OutputReport,
    now: rove_core::MonoTime,
) -> String {
    // Devices, not streams: an operator holding a grant may have two live writers.
    let live = arbiter
        .sources(now)
        .filter(|s| s.live)
        .map(|s| s.controller.device)
        .collect::<std::collections::BTreeSet<_>>()
        .len();
    let operators = match live {
        0 => "no operator live".to_string(),
        1 => "1 operator live".to_string(),
        n => format!("{n} operators live"),
    };
    let owner = match arbiter.owner().device() {
        Some(id) => format!("driven by {id}"),
        None => "failsafe".to_string(),
    };
    format!("{owner} ({operators}); output {output}")
}

/// Watches the output's thread for a device call that does not return: logs when one hangs and
/// when it returns, and stops the watchdog keep-alives once it has been hung for `limit`.
#[derive(Debug)]
pub(super) struct HungWatch {
    limit: Duration,
    hung: bool,
    stopped: bool,
}

impl HungWatch {
    /// The end of `STATUS=` while the keep-alives are stopped.
    pub(super) const STOPPED: &str = "; watchdog keep-alives stopped";

    pub(super) fn new(limit: Duration) -> HungWatch {
        HungWatch {
            limit,
            hung: false,
            stopped: false,
        }
    }

    pub(super) fn observe(&mut self, report: &OutputReport) {
        match (report.hung, self.hung) {
            (Some(hung), false) => warn!(
                hung_ms = hung.as_millis() as u64,
                output = %report.describe,
                "output hung: a device call has not returned; the vehicle goes on deciding, the \
                 outputs change when it returns"
            ),
            (None, true) => info!(output = %report.health, "output call returned"),
            _ => {}
        }
        self.hung = report.hung.is_some();
    }

    /// Whether the watchdog keep-alive may be sent now.
    pub(super) fn keepalive(&mut self, report: &OutputReport) -> bool {
        self.observe(report);
        let over = report.hung.is_some_and(|h| h > self.limit);
        if over && !self.stopped {
            warn!(
                limit_ms = self.limit.as_millis() as u64,
                "output hung longer than [vehicle] output_hung_limit_ms: watchdog keep-alives \
                 stopped, so that systemd restarts the unit"
            );
        }
        self.stopped = over;
        !over
    }

    pub(super) fn annotate(&self, line: String) -> String {
        match self.stopped && !line.ends_with(Self::STOPPED) {
            true => line + Self::STOPPED,
            false => line,
        }
    }
}

/// Messages the arbiter did not believe: the first from each participant is logged at once,
/// then at most one per [`RateLimited::INTERVAL`](crate::runtime::RateLimited::INTERVAL) (a
/// rogue inventing ids cannot flood the journal); all are counted.
#[derive(Debug, Default)]
pub(super) struct Suspects {
    logged: HashMap<ParticipantId, std::time::Instant>,
    total: u64,
    last: Option<Suspect>,
}

impl Suspects {
    /// Participants remembered for rate limiting; beyond it the table starts afresh.
    pub(super) const MAX_PARTICIPANTS: usize = 256;

    pub(super) fn report(&mut self, suspect: Suspect) {
        self.total += 1;
        self.last = Some(suspect);
        let key = suspect.sender;
        let interval = crate::runtime::RateLimited::INTERVAL;
        if self
            .logged
            .get(&key)
            .is_some_and(|t| t.elapsed() < interval)
        {
            return;
        }
        if self.logged.len() >= Self::MAX_PARTICIPANTS {
            self.logged.clear();
        }
        self.logged.insert(key, std::time::Instant::now());
        warn!(
            device = suspect.device,
            participant = %suspect.sender,
            total = self.total,
            "not believed: {suspect}"
        );
    }

    /// `line` with the count and the last one, once there is one.
    pub(super) fn annotate(&self, line: String) -> String {
        match &self.last {
            Some(last) => format!(
                "{line}; {} untrusted messages ignored (last: device {} from participant {})",
                self.total, last.device, last.sender
            ),
            None => line,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rove_core::MonoTime;
    use rove_core::arbiter::{ArbiterConfig, Event, WriterId};
    use rove_core::hierarchy::Strength;
    use rove_core::msg::{CommandType, ControlCommand, Mode, MovementCommand, TimeT};

    fn sample(writer: WriterId, device: i64, strength: u16, at: MonoTime) -> Event {
        Event::Sample {
            writer,
            strength: Strength(strength),
            command: ControlCommand {
                src_id: device,
                dest_id: 100,
                command_type: CommandType::Movement,
                movement_command: MovementCommand::default(),
                mode: Mode::Manual,
                timestamp: TimeT(0),
            },
            arrival: at,
        }
    }

    #[test]
    fn status_line_names_the_owner_counts_live_devices_and_shows_output_health() {
        let mut output = OutputReport {
            describe: "sim".into(),
            health: rove_core::adapter::Health::Ok,
            detail: None,
            hung: None,
            stale: 0,
            held_safe: false,
            telemetry: Default::default(),
        };
        let mut arbiter = Arbiter::new(100, ArbiterConfig::default());
        let t = MonoTime::ZERO;
        assert_eq!(
            status_line(&arbiter, &output, t),
            "failsafe (no operator live); output ok"
        );
        let writer = |p: u128, e: u32| WriterId {
            participant: ParticipantId(p),
            entity: e,
        };
        // Device 11 streams on two writers (regular and priority): one operator.
        arbiter.step(t, sample(writer(1, 1), 11, 220, t));
        arbiter.step(t, sample(writer(1, 2), 11, 65535, t));
        arbiter.step(t, sample(writer(2, 1), 12, 110, t));
        assert_eq!(
            status_line(&arbiter, &output, t),
            "driven by 11 (2 operators live); output ok"
        );
        // One command timeout later nobody is live.
        let later = t + std::time::Duration::from_secs(1);
        arbiter.step(later, Event::Tick);
        assert_eq!(
            status_line(&arbiter, &output, later),
            "failsafe (no operator live); output ok"
        );
        // A device call that does not return.
        output.hung = Some(Duration::from_millis(1250));
        assert_eq!(
            status_line(&arbiter, &output, later),
            "failsafe (no operator live); output hung: a device call has not returned for 1.2s"
        );
    }

    /// Issue 30: an autopilot that refused the owner's mode, with the adapter holding the
    /// outputs safe, is reported as failsafe while the owner still owns the vehicle.
    #[test]
    fn status_says_failsafe_while_the_adapter_holds_the_outputs_safe() {
        let mut arbiter = Arbiter::new(100, ArbiterConfig::default());
        let t = MonoTime::ZERO;
        let writer = WriterId {
            participant: ParticipantId(1),
            entity: 1,
        };
        arbiter.step(t, sample(writer, 11, 220, t));
        let mut report = OutputReport {
            describe: "mavlink".into(),
            health: rove_core::adapter::Health::Degraded("AUTO refused".into()),
            detail: None,
            hung: None,
            stale: 0,
            held_safe: false,
            telemetry: Default::default(),
        };
        let driving = vehicle_status(100, &arbiter, rove_core::msg::Mode::Auto, &report);
        assert_eq!((driving.controller_id, driving.failsafe), (11, false));
        report.held_safe = true;
        let held = vehicle_status(100, &arbiter, rove_core::msg::Mode::Auto, &report);
        assert_eq!((held.controller_id, held.failsafe), (11, true));
        assert!(held.health.held, "the hold is the output's own decision");
    }

    /// The autopilot's battery and mode go out in VehicleStatus; a change of health alone at
    /// most once per [`HEALTH_PERIOD`], any other change at once; low at the configured level.
    #[test]
    fn health_is_published_on_change_at_most_once_a_second() {
        use rove_core::adapter::Telemetry;
        let mut arbiter = Arbiter::new(100, ArbiterConfig::default());
        let mut watch = StatusWatch::new(100, 25);
        let mut report = OutputReport {
            describe: "mavlink".into(),
            health: rove_core::adapter::Health::Ok,
            detail: None,
            hung: None,
            stale: 0,
            held_safe: false,
            telemetry: Telemetry {
                battery_mv: Some(11_400),
                battery_pct: Some(26),
                autopilot_mode: Some("HOLD".into()),
                armed: Some(false),
                link_age: Some(Duration::from_millis(300)),
            },
        };
        let at = |ms| MonoTime::from_millis(ms);
        let first = watch.changed(&arbiter, &report, at(0)).cloned();
        let health = first.map(|s| s.health).expect("the first status goes out");
        assert_eq!(
            (health.battery_mv, health.battery_pct, health.battery_low),
            (11_400, 26, false)
        );
        assert_eq!(
            (health.autopilot_mode.as_str(), health.link_age_ms),
            ("HOLD", 300)
        );
        // Health alone: held back until a second has passed, then sent with the newest values.
        report.telemetry.battery_pct = Some(25);
        assert!(watch.changed(&arbiter, &report, at(500)).is_none());
        report.telemetry.link_age = Some(Duration::from_millis(800));
        let later = watch.changed(&arbiter, &report, at(1_000)).cloned();
        let health = later.map(|s| s.health).expect("a second later");
        assert_eq!((health.battery_pct, health.battery_low), (25, true));
        assert_eq!(health.link_age_ms, 800);
        // An owner change goes out at once, with the health as it is.
        let writer = WriterId {
            participant: ParticipantId(1),
            entity: 1,
        };
        report.telemetry.battery_pct = Some(24);
        arbiter.step(at(1_100), sample(writer, 11, 220, at(1_100)));
        let owned = watch.changed(&arbiter, &report, at(1_100)).cloned();
        assert_eq!(
            owned.map(|s| (s.controller_id, s.health.battery_pct)),
            Some((11, 24))
        );
        assert!(
            watch.changed(&arbiter, &report, at(1_200)).is_none(),
            "unchanged"
        );
        // Nothing known: the wire's unknown values, never low.
        report.telemetry = Telemetry::default();
        let unknown = vehicle_status(100, &arbiter, rove_core::msg::Mode::Manual, &report);
        assert_eq!(unknown.health, rove_core::msg::VehicleHealth::UNKNOWN);
    }

    #[test]
    fn keepalives_stop_only_once_the_output_is_hung_past_its_limit() {
        let mut watch = HungWatch::new(Duration::from_secs(2));
        let report = |hung_ms: Option<u64>| OutputReport {
            describe: "pwm".into(),
            health: rove_core::adapter::Health::Ok,
            detail: None,
            hung: hung_ms.map(Duration::from_millis),
            stale: 0,
            held_safe: false,
            telemetry: Default::default(),
        };
        assert!(watch.keepalive(&report(None)));
        assert!(watch.keepalive(&report(Some(60))));
        assert!(watch.keepalive(&report(Some(2000))));
        assert_eq!(watch.annotate("x".into()), "x");
        assert!(!watch.keepalive(&report(Some(2001))));
        assert_eq!(
            watch.annotate("x".into()),
            "x; watchdog keep-alives stopped"
        );
        assert_eq!(
            watch.annotate(watch.annotate("x".into())),
            "x; watchdog keep-alives stopped"
        );
        // The call returned: keep-alives again.
        assert!(watch.keepalive(&report(None)));
        assert_eq!(watch.annotate("x".into()), "x");
    }
}
