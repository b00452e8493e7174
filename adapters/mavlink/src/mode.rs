//! Mode changes: send MAV_CMD_DO_SET_MODE, confirm it from COMMAND_ACK or the autopilot's
//! HEARTBEAT, resend a bounded number of times. Pure: stepped with `now`.
//!
//! A mode is commanded when rove's wish changes (the operator's mode, or entering failsafe), and
//! again when the link comes back ([`ModeControl::reassert`]; ArduPilot leaves its GCS failsafe in
//! HOLD). It is *not* enforced continuously: a pilot who flips the radio's mode switch while rove
//! drives keeps the mode they chose until rove's wish changes.

use crate::config::AutopilotMode;
use rove_core::MonoTime;
use std::time::Duration;

/// What a COMMAND_ACK said, reduced to what the machine needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AckResult {
    /// MAV_RESULT_ACCEPTED.
    Accepted,
    /// MAV_RESULT_IN_PROGRESS: wait one more timeout.
    InProgress,
    /// MAV_RESULT_TEMPORARILY_REJECTED: resend after the timeout, like no answer.
    TemporarilyRejected,
    /// DENIED, UNSUPPORTED, FAILED, CANCELLED…: give up, with the result's name.
    Refused(&'static str),
}

/// Where the current mode wish stands.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ModeState {
    /// No mode wished yet.
    Idle,
    /// Sent `attempts` times, not confirmed yet.
    Pending {
        /// The mode.
        mode: AutopilotMode,
        /// Sends so far.
        attempts: u32,
    },
    /// The autopilot acknowledged it or reports it.
    Confirmed(AutopilotMode),
    /// Refused, or no answer after every resend.
    Failed {
        /// The mode.
        mode: AutopilotMode,
        /// Why.
        reason: String,
    },
}

/// The mode-command machine.
#[derive(Debug, Clone)]
pub struct ModeControl {
    timeout: Duration,
    retries: u32,
    state: ModeState,
    next_send: Option<MonoTime>,
}

impl ModeControl {
    /// A machine that waits `timeout` for an answer and resends `retries` times.
    pub fn new(timeout: Duration, retries: u32) -> Self {
        ModeControl {
            timeout,
            retries,
            state: ModeState::Idle,
            next_send: None,
        }
    }

    /// The current state.
    pub fn state(&self) -> &ModeState {
        &self.state
    }

    /// The wished mode, whatever its state.
    pub fn wished(&self) -> Option<&AutopilotMode> {
        match &self.state {
            ModeState::Idle => None,
            ModeState::Pending { mode, .. }
            | ModeState::Confirmed(mode)
            | ModeState::Failed { mode, .. } => Some(mode),
        }
    }

    /// Wish for `mode`; a no-op if it is already the wish. The first send is due at once.
    pub fn request(&mut self, now: MonoTime, mode: &AutopilotMode) {
        if self.wished() != Some(mode) {
            self.start(now, mode.clone());
        }
    }

    /// Sends the current wish again from the first attempt (the link came back).
    pub fn reassert(&mut self, now: MonoTime) {
        if let Some(mode) = self.wished().cloned() {
            self.start(now, mode);
        }
    }

    fn start(&mut self, now: MonoTime, mode: AutopilotMode) {
        self.state = ModeState::Pending { mode, attempts: 0 };
        self.next_send = Some(now);
    }

    /// When [`ModeControl::poll`] has work.
    pub fn next_deadline(&self) -> Option<MonoTime> {
        self.next_send
    }

    /// The custom_mode to send now, if a send (first or resend) is due.
    pub fn poll(&mut self, now: MonoTime) -> Option<u32> {
        let due = self.next_send.is_some_and(|t| now >= t);
        let ModeState::Pending { mode, attempts } = &mut self.state else {
            self.next_send = None;
            return None;
        };
        if !due {
            return None;
        }
        if *attempts > self.retries {
            let reason = format!(
                "no COMMAND_ACK or HEARTBEAT in {} after {} sends of {}",
                mode.name, attempts, "MAV_CMD_DO_SET_MODE"
            );
            self.state = ModeState::Failed {
                mode: mode.clone(),
                reason,
            };
            self.next_send = None;
            return None;
        }
        *attempts += 1;
        self.next_send = Some(now + self.timeout);
        Some(mode.custom_mode)
    }

    /// A COMMAND_ACK for MAV_CMD_DO_SET_MODE from the target arrived.
    pub fn on_ack(&mut self, now: MonoTime, result: AckResult) {
        let ModeState::Pending { mode, .. } = &self.state else {
            return;
        };
        match result {
            AckResult::Accepted => {
                self.state = ModeState::Confirmed(mode.clone());
                self.next_send = None;
            }
            AckResult::InProgress => self.next_send = Some(now + self.timeout),
            AckResult::TemporarilyRejected => {}
            AckResult::Refused(name) => {
                self.state = ModeState::Failed {
                    mode: mode.clone(),
                    reason: format!("the autopilot answered {name} to {}", mode.name),
                };
                self.next_send = None;
            }
        }
    }

    /// The target's HEARTBEAT reports `custom_mode`.
    ///
    /// It confirms only a wish that was sent at least once: a HEARTBEAT read before the command
    /// left may be stale (bytes a serial line or socket held from before), and a safe mode is
    /// always commanded rather than assumed.
    pub fn on_heartbeat(&mut self, custom_mode: u32) {
        let sent = match &self.state {
            ModeState::Pending { attempts, .. } => *attempts > 0,
            _ => true,
        };
        if sent
            && let ModeState::Pending { mode, .. } | ModeState::Failed { mode, .. } = &self.state
            && mode.custom_mode == custom_mode
        {
            self.state = ModeState::Confirmed(mode.clone());
            self.next_send = None;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hold() -> AutopilotMode {
        AutopilotMode {
            name: "HOLD".into(),
            custom_mode: 4,
        }
    }

    fn manual() -> AutopilotMode {
        AutopilotMode {
            name: "MANUAL".into(),
            custom_mode: 0,
        }
    }

    fn ms(v: u64) -> MonoTime {
        MonoTime::from_millis(v)
    }

    fn machine() -> ModeControl {
        ModeControl::new(Duration::from_millis(300), 3)
    }

    #[test]
    fn sends_at_once_and_stops_on_accept() {
        let mut m = machine();
        m.request(ms(0), &hold());
        assert_eq!(m.poll(ms(0)), Some(4));
        assert_eq!(m.poll(ms(100)), None, "waits for the answer");
        m.on_ack(ms(120), AckResult::Accepted);
        assert_eq!(m.state(), &ModeState::Confirmed(hold()));
        assert_eq!(m.poll(ms(1000)), None);
        assert_eq!(m.next_deadline(), None);
    }

    #[test]
    fn resends_on_silence_then_gives_up() {
        let mut m = machine();
        m.request(ms(0), &hold());
        let mut sends = Vec::new();
        for t in (0..3000).step_by(10) {
            if m.poll(ms(t)).is_some() {
                sends.push(t);
            }
        }
        assert_eq!(sends, vec![0, 300, 600, 900], "1 send + 3 resends");
        assert!(
            matches!(m.state(), ModeState::Failed { reason, .. } if reason.contains("4 sends"))
        );
    }

    #[test]
    fn heartbeat_confirms_even_without_ack() {
        let mut m = machine();
        m.request(ms(0), &hold());
        assert_eq!(m.poll(ms(0)), Some(4));
        m.on_heartbeat(0);
        assert!(matches!(m.state(), ModeState::Pending { .. }), "other mode");
        m.on_heartbeat(4);
        assert_eq!(m.state(), &ModeState::Confirmed(hold()));
    }

    #[test]
    fn refusal_stops_and_names_the_result() {
        let mut m = machine();
        m.request(ms(0), &hold());
        m.poll(ms(0));
        m.on_ack(ms(10), AckResult::Refused("MAV_RESULT_DENIED"));
        assert!(matches!(m.state(), ModeState::Failed { reason, .. } if reason.contains("DENIED")));
        assert_eq!(m.poll(ms(1000)), None);
    }

    #[test]
    fn in_progress_extends_and_temporary_rejection_resends() {
        let mut m = machine();
        m.request(ms(0), &hold());
        m.poll(ms(0));
        m.on_ack(ms(250), AckResult::InProgress);
        assert_eq!(m.poll(ms(300)), None, "in progress: wait from the ack");
        assert_eq!(m.poll(ms(550)), Some(4));
        m.on_ack(ms(560), AckResult::TemporarilyRejected);
        assert_eq!(m.poll(ms(850)), Some(4));
    }

    #[test]
    fn same_wish_is_not_resent_but_a_new_one_and_reassert_are() {
        let mut m = machine();
        m.request(ms(0), &manual());
        m.poll(ms(0));
        m.on_ack(ms(5), AckResult::Accepted);
        m.request(ms(10), &manual());
        assert_eq!(m.poll(ms(10)), None, "unchanged wish");
        m.reassert(ms(20));
        assert_eq!(m.poll(ms(20)), Some(0), "link back: resent");
        m.request(ms(30), &hold());
        assert_eq!(m.poll(ms(30)), Some(4), "new wish sent at once");
    }

    #[derive(Debug, Clone)]
    enum Step {
        Poll(u64),
        Ack(u8),
        Heartbeat(u32),
        Wish(bool),
        Reassert,
    }

    fn step() -> impl proptest::strategy::Strategy<Value = Step> {
        use proptest::prelude::*;
        prop_oneof![
            4 => (0u64..400).prop_map(Step::Poll),
            1 => (0u8..4).prop_map(Step::Ack),
            1 => prop_oneof![Just(0u32), Just(4), Just(7)].prop_map(Step::Heartbeat),
            1 => any::<bool>().prop_map(Step::Wish),
            1 => Just(Step::Reassert),
        ]
    }

    proptest::proptest! {
        /// Whatever the autopilot answers, a wish is sent at most 1 + retries times between two
        /// (re)starts, never after it is settled, and only the wished mode is ever sent.
        #[test]
        fn sends_are_bounded_and_only_for_the_wish(steps in proptest::collection::vec(step(), 0..200)) {
            let mut m = machine();
            let mut now = 0u64;
            let mut sends_since_start = 0u32;
            for s in steps {
                match s {
                    Step::Poll(dt) => {
                        now += dt;
                        if let Some(mode) = m.poll(ms(now)) {
                            sends_since_start += 1;
                            proptest::prop_assert_eq!(Some(mode), m.wished().map(|w| w.custom_mode));
                            proptest::prop_assert!(sends_since_start <= 4, "{} sends", sends_since_start);
                        }
                    }
                    Step::Ack(k) => m.on_ack(ms(now), match k {
                        0 => AckResult::Accepted,
                        1 => AckResult::InProgress,
                        2 => AckResult::TemporarilyRejected,
                        _ => AckResult::Refused("MAV_RESULT_DENIED"),
                    }),
                    Step::Heartbeat(mode) => m.on_heartbeat(mode),
                    Step::Wish(hold_wanted) => {
                        let wish = if hold_wanted { hold() } else { manual() };
                        if m.wished() != Some(&wish) {
                            sends_since_start = 0;
                        }
                        m.request(ms(now), &wish);
                    }
                    Step::Reassert => {
                        if m.wished().is_some() {
                            sends_since_start = 0;
                        }
                        m.reassert(ms(now));
                    }
                }
                if matches!(m.state(), ModeState::Confirmed(_) | ModeState::Failed { .. }) {
                    proptest::prop_assert_eq!(m.poll(ms(now + 10_000)), None);
                }
            }
        }
    }

    #[test]
    fn a_heartbeat_before_the_first_send_confirms_nothing() {
        let mut m = machine();
        m.request(ms(0), &hold());
        m.on_heartbeat(4);
        assert!(matches!(m.state(), ModeState::Pending { attempts: 0, .. }));
        assert_eq!(m.poll(ms(0)), Some(4), "the safe mode is commanded anyway");
        m.on_heartbeat(4);
        assert_eq!(m.state(), &ModeState::Confirmed(hold()));
    }

    #[test]
    fn acks_without_a_pending_wish_change_nothing() {
        let mut m = machine();
        m.on_ack(ms(0), AckResult::Accepted);
        m.on_heartbeat(4);
        assert_eq!(m.state(), &ModeState::Idle);
    }
}
