//! Sticks from a remote front end (the browser console, `gateway/src/web`): the stale-input
//! rules of a link that can go quiet, be hidden or drop, as a pure state machine.
//!
//! The front end sends a [`Frame`] at its stream rate (the sticks and whether its deadman is
//! held: a finger on a touch stick, or a held gamepad button), even when nothing changed, so
//! that silence means a dead link. [`RemoteInput`] turns frames, losses and the passing of time
//! into the same [`InputEvent`]s an evdev device produces, so the operator session treats a
//! browser like any input.
//!
//! # Rules
//! - **Deadman.** Axes go out only while the deadman is held. Letting go emits
//!   `Deadman(false)` (the session releases every vehicle explicitly, at once).
//! - **Lost.** [`RemoteInput::lost`] (page hidden, screen locked, connection closed) and a
//!   silence longer than the configured limit emit one `Lost`; nothing more until frames come
//!   again.
//! - **No jump.** At start, after `Lost` and after the deadman is let go, no `Axes` is emitted
//!   until a frame has the deadman held and every axis within [`REST_TOLERANCE`] of centre. That
//!   first `Axes` is the "live again" signal; later frames emit `Axes` when the sticks change.
//!   A reconnecting page whose finger is still pushed forward therefore moves nothing until the
//!   stick comes back to centre.
//!
//! Nothing here reads a clock: every call takes `now`.

use crate::adapter::InputEvent;
use crate::msg::{AXIS_MAX, MovementCommand};
use crate::time::MonoTime;
use std::collections::VecDeque;
use std::time::Duration;

/// How close to centre every axis must be to (re)start driving: 5 % of full scale, as for evdev
/// devices (a thumb that rests lightly on a touch stick is not perfectly centred).
pub const REST_TOLERANCE: f64 = 0.05;

/// Bound on queued events: a caller that stops polling must not grow memory. Frames only add
/// an event on a change, so 64 is many frames' worth; when full the oldest `Axes` goes first.
pub const MAX_QUEUED: usize = 64;

/// One report from the front end.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frame {
    /// The sticks.
    pub sticks: MovementCommand,
    /// The deadman is held.
    pub deadman: bool,
}

/// Where the link is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RemoteLink {
    /// Not connected yet, or lost (with why): waiting for frames.
    Lost(String),
    /// Frames arrive; waiting for a held deadman with centred sticks.
    AwaitingCentre,
    /// Driving: the deadman is held and the sticks went through centre.
    Live,
}

/// The state machine (module docs).
#[derive(Debug, Clone)]
pub struct RemoteInput {
    silence: Duration,
    /// Who sends the frames, for the lost line.
    what: &'static str,
    link: RemoteLink,
    last_frame: Option<MonoTime>,
    deadman: bool,
    sticks: MovementCommand,
    out: VecDeque<InputEvent>,
}

/// Whether every axis is within [`REST_TOLERANCE`] of centre.
pub fn is_centred(m: &MovementCommand) -> bool {
    let limit = REST_TOLERANCE * f64::from(AXIS_MAX);
    [m.throttle, m.roll, m.pitch, m.yaw]
        .iter()
        .all(|&a| f64::from(a).abs() <= limit)
}

impl RemoteInput {
    /// A link that counts as lost after `silence` without a frame; not connected yet.
    pub fn new(silence: Duration) -> RemoteInput {
        RemoteInput::named(silence, "the browser")
    }

    /// As [`RemoteInput::new`], for frames from `what` (said when it goes quiet).
    pub fn named(silence: Duration, what: &'static str) -> RemoteInput {
        RemoteInput {
            silence,
            what,
            link: RemoteLink::Lost(format!("nothing from {what} yet")),
            last_frame: None,
            deadman: false,
            sticks: MovementCommand::CENTRED,
            out: VecDeque::new(),
        }
    }

    /// A frame arrived at `now`.
    pub fn frame(&mut self, now: MonoTime, frame: Frame) {
        self.last_frame = Some(now);
        if matches!(self.link, RemoteLink::Lost(_)) {
            self.link = RemoteLink::AwaitingCentre;
        }
        let was_held = self.deadman;
        self.deadman = frame.deadman;
        if was_held && !frame.deadman {
            self.push(InputEvent::Deadman(false));
            if self.link == RemoteLink::Live {
                self.link = RemoteLink::AwaitingCentre;
            }
        } else if !was_held && frame.deadman {
            self.push(InputEvent::Deadman(true));
        }
        let changed = frame.sticks != self.sticks;
        self.sticks = frame.sticks;
        match self.link {
            RemoteLink::AwaitingCentre if frame.deadman && is_centred(&frame.sticks) => {
                self.link = RemoteLink::Live;
                self.push(InputEvent::Axes(frame.sticks));
            }
            RemoteLink::Live if changed => self.push(InputEvent::Axes(frame.sticks)),
            _ => {}
        }
    }

    /// The front end is gone or cannot be trusted now (hidden page, closed connection).
    pub fn lost(&mut self, reason: &str) {
        if !matches!(self.link, RemoteLink::Lost(_)) {
            self.link = RemoteLink::Lost(reason.to_string());
            self.push(InputEvent::Lost {
                reason: reason.to_string(),
            });
        }
        self.deadman = false;
        self.last_frame = None;
    }

    /// Advances time: a silence longer than the limit is a loss.
    pub fn tick(&mut self, now: MonoTime) {
        if let Some(deadline) = self.next_deadline()
            && now >= deadline
        {
            let ms = self.silence.as_millis();
            self.lost(&format!("no input from {} for {ms} ms", self.what));
        }
    }

    /// When [`tick`](Self::tick) next has something to do.
    pub fn next_deadline(&self) -> Option<MonoTime> {
        match self.link {
            RemoteLink::Lost(_) => None,
            _ => self.last_frame.map(|t| t + self.silence),
        }
    }

    /// The next event, oldest first.
    pub fn pop(&mut self) -> Option<InputEvent> {
        self.out.pop_front()
    }

    /// The link, for displays.
    pub fn link(&self) -> &RemoteLink {
        &self.link
    }

    /// Whether the deadman is held now.
    pub fn deadman(&self) -> bool {
        self.deadman
    }

    fn push(&mut self, event: InputEvent) {
        if self.out.len() >= MAX_QUEUED {
            match self
                .out
                .iter()
                .position(|e| matches!(e, InputEvent::Axes(_)))
            {
                Some(i) => {
                    self.out.remove(i);
                }
                None => {
                    self.out.pop_front();
                }
            }
        }
        self.out.push_back(event);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const SILENCE: Duration = Duration::from_millis(200);

    fn ms(t: u64) -> MonoTime {
        MonoTime::from_millis(t)
    }

    fn frame(throttle: i16, deadman: bool) -> Frame {
        Frame {
            sticks: MovementCommand {
                throttle,
                ..MovementCommand::CENTRED
            },
            deadman,
        }
    }

    fn drain(r: &mut RemoteInput) -> Vec<InputEvent> {
        std::iter::from_fn(|| r.pop()).collect()
    }

    fn axes(throttle: i16) -> InputEvent {
        InputEvent::Axes(frame(throttle, true).sticks)
    }

    #[test]
    fn drives_only_after_a_held_deadman_with_centred_sticks() {
        let mut r = RemoteInput::new(SILENCE);
        r.frame(ms(0), frame(0, false));
        assert_eq!(drain(&mut r), vec![]);
        r.frame(ms(20), frame(20_000, true));
        assert_eq!(drain(&mut r), vec![InputEvent::Deadman(true)]);
        r.frame(ms(40), frame(0, true));
        assert_eq!(drain(&mut r), vec![axes(0)]);
        r.frame(ms(60), frame(8_000, true));
        r.frame(ms(80), frame(8_000, true));
        assert_eq!(drain(&mut r), vec![axes(8_000)], "only changes");
        assert_eq!(r.link(), &RemoteLink::Live);
    }

    #[test]
    fn letting_go_releases_and_a_push_without_centring_moves_nothing() {
        let mut r = RemoteInput::new(SILENCE);
        r.frame(ms(0), frame(0, true));
        r.frame(ms(20), frame(9_000, true));
        drain(&mut r);
        r.frame(ms(40), frame(9_000, false));
        assert_eq!(drain(&mut r), vec![InputEvent::Deadman(false)]);
        // Held again while pushed: waits for centre.
        r.frame(ms(60), frame(9_000, true));
        r.frame(ms(80), frame(5_000, true));
        assert_eq!(drain(&mut r), vec![InputEvent::Deadman(true)]);
        r.frame(ms(100), frame(1_000, true));
        assert_eq!(drain(&mut r), vec![axes(1_000)], "1 000 is within 5 %");
    }

    #[test]
    fn silence_is_lost_once_and_frames_resume_through_centre() {
        let mut r = RemoteInput::new(SILENCE);
        r.frame(ms(0), frame(0, true));
        r.frame(ms(20), frame(12_000, true));
        drain(&mut r);
        assert_eq!(r.next_deadline(), Some(ms(220)));
        r.tick(ms(219));
        assert_eq!(drain(&mut r), vec![]);
        r.tick(ms(220));
        let lost = drain(&mut r);
        assert!(
            matches!(&lost[..], [InputEvent::Lost { reason }] if reason.contains("200 ms")),
            "{lost:?}"
        );
        r.tick(ms(900));
        assert_eq!(r.next_deadline(), None);
        assert_eq!(drain(&mut r), vec![], "lost once");
        // The page comes back with the finger still forward.
        r.frame(ms(1_000), frame(12_000, true));
        assert_eq!(drain(&mut r), vec![InputEvent::Deadman(true)]);
        r.frame(ms(1_020), frame(0, true));
        assert_eq!(drain(&mut r), vec![axes(0)]);
    }

    #[test]
    fn an_explicit_loss_is_told_once() {
        let mut r = RemoteInput::new(SILENCE);
        r.lost("page hidden");
        assert_eq!(drain(&mut r), vec![], "never connected: nothing to release");
        r.frame(ms(0), frame(0, true));
        drain(&mut r);
        r.lost("page hidden");
        r.lost("connection closed");
        let events = drain(&mut r);
        assert_eq!(
            events,
            vec![InputEvent::Lost {
                reason: "page hidden".into()
            }]
        );
        assert!(!r.deadman());
    }

    #[test]
    fn the_queue_is_bounded_and_keeps_releases() {
        let mut r = RemoteInput::new(SILENCE);
        r.frame(ms(0), frame(0, true));
        for i in 0..500u16 {
            let held = i % 50 != 49;
            r.frame(
                ms(1 + u64::from(i)),
                frame(i16::try_from(i).unwrap_or(0) * 60, held),
            );
        }
        let events = drain(&mut r);
        assert!(events.len() <= MAX_QUEUED);
        assert!(events.contains(&InputEvent::Deadman(false)));
    }

    fn any_frame() -> impl Strategy<Value = Frame> {
        (any::<i16>(), any::<i16>(), any::<bool>()).prop_map(|(throttle, roll, deadman)| Frame {
            sticks: MovementCommand {
                throttle,
                roll,
                ..MovementCommand::CENTRED
            },
            deadman,
        })
    }

    proptest! {
        /// Whatever the frames, losses and gaps: no `Axes` while the deadman is not held, and
        /// the first `Axes` after a start, a loss or a release is centred.
        #[test]
        fn never_moves_without_deadman_or_from_off_centre(
            steps in proptest::collection::vec((any_frame(), 0u64..400, any::<bool>()), 1..200),
        ) {
            let mut r = RemoteInput::new(SILENCE);
            let mut t = 0;
            let mut must_centre = true;
            for (f, gap, lose) in steps {
                t += gap;
                r.tick(ms(t));
                if lose {
                    r.lost("hidden");
                }
                r.frame(ms(t), f);
                for e in drain(&mut r) {
                    match e {
                        InputEvent::Axes(m) => {
                            prop_assert!(f.deadman);
                            if must_centre {
                                prop_assert!(is_centred(&m));
                            }
                            must_centre = false;
                        }
                        InputEvent::Deadman(false) | InputEvent::Lost { .. } => must_centre = true,
                        _ => {}
                    }
                }
            }
        }
    }
}
