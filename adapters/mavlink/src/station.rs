//! A ground station that is an operator of the hierarchy (`[[output.gcs]] id = …`,
//! docs/mavlink.md, "A ground station in the hierarchy"): what its port heard of it, shared with
//! the operator loop the gateway runs for it ([`rove_core::adapter::HostedLink`]), and the
//! hierarchy's answers to its requests. Its MANUAL_CONTROL never goes to the autopilot raw: it
//! becomes that operator's sticks, and rove's own control message carries whoever drives.
//!
//! Also pure helpers: MANUAL_CONTROL's axes as rove's sticks.

use rove_core::adapter::{HostedEvent, HostedLink};
use rove_core::msg::{AXIS_MAX, MovementCommand};
use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};

/// Events kept for a loop that does not take them: beyond, the oldest sticks go first.
const MAX_EVENTS: usize = 64;

/// What a station's port shares with its operator loop.
pub struct Feed {
    /// Names the station in the log: `QGC (50) on udpout:…`.
    what: String,
    state: Mutex<FeedState>,
    /// Called when an answer or a change of control is told ([`Feed::set_nudge`]).
    nudge: Mutex<Option<Nudge>>,
}

type Nudge = Box<dyn Fn() + Send + Sync>;

#[derive(Default)]
struct FeedState {
    events: VecDeque<HostedEvent>,
    waker: Option<Arc<dyn Fn() + Send + Sync>>,
    /// Answers to the station's requests not sent yet (true: granted), oldest first.
    answers: VecDeque<bool>,
    /// It holds control in the hierarchy.
    holds: bool,
}

impl std::fmt::Debug for Feed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.what)
    }
}

fn lock(m: &Mutex<FeedState>) -> MutexGuard<'_, FeedState> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

impl Feed {
    /// A feed for the station `what` names.
    pub fn new(what: String) -> Feed {
        Feed {
            what,
            state: Mutex::default(),
            nudge: Mutex::new(None),
        }
    }

    /// `nudge` is called (on the caller's thread) whenever the hierarchy answers or control
    /// changes hands, so that the station hears it at once.
    pub fn set_nudge(&self, nudge: Nudge) {
        *self.nudge.lock().unwrap_or_else(PoisonError::into_inner) = Some(nudge);
    }

    fn nudge(&self) {
        if let Some(nudge) = &*self.nudge.lock().unwrap_or_else(PoisonError::into_inner) {
            nudge();
        }
    }

    /// The port heard `event` from the station.
    pub fn heard(&self, event: HostedEvent) {
        let mut s = lock(&self.state);
        if s.events.len() >= MAX_EVENTS {
            let oldest_sticks =
                (s.events.iter()).position(|e| matches!(e, HostedEvent::Sticks(..)));
            match oldest_sticks {
                Some(i) => drop(s.events.remove(i)),
                None => drop(s.events.pop_front()),
            }
        }
        s.events.push_back(event);
        let waker = s.waker.clone();
        drop(s);
        if let Some(wake) = waker {
            wake();
        }
    }

    /// The hierarchy's answers not sent to the station yet, oldest first.
    pub fn take_answers(&self) -> Vec<bool> {
        lock(&self.state).answers.drain(..).collect()
    }

    /// Whether it holds control in the hierarchy (its operator loop says).
    pub fn holding(&self) -> bool {
        lock(&self.state).holds
    }
}

impl HostedLink for Feed {
    fn describe(&self) -> String {
        self.what.clone()
    }

    fn take(&self) -> Vec<HostedEvent> {
        lock(&self.state).events.drain(..).collect()
    }

    fn set_waker(&self, waker: Arc<dyn Fn() + Send + Sync>) {
        lock(&self.state).waker = Some(waker);
    }

    fn answered(&self, granted: bool) {
        let mut s = lock(&self.state);
        if s.answers.len() < MAX_EVENTS {
            s.answers.push_back(granted);
        }
        drop(s);
        self.nudge();
    }

    fn holds(&self, control: bool) {
        lock(&self.state).holds = control;
        self.nudge();
    }
}

/// MANUAL_CONTROL's axes (−1000..1000; `z` 0..1000 on ArduPilot's and QGroundControl's
/// convention for throttle, centred at 500) as rove's sticks: `x` pitch, `y` roll, `z`
/// throttle, `r` yaw. Out-of-range values are clamped.
pub fn sticks(x: i16, y: i16, z: i16, r: i16) -> MovementCommand {
    let scale = |v: i32| {
        let v = v.clamp(-1000, 1000);
        i16::try_from(v * i32::from(AXIS_MAX) / 1000).unwrap_or(0)
    };
    MovementCommand {
        throttle: scale((i32::from(z) - 500) * 2),
        roll: scale(i32::from(y)),
        pitch: scale(i32::from(x)),
        yaw: scale(i32::from(r)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn manual_control_maps_to_sticks_centred_at_rest() {
        assert_eq!(sticks(0, 0, 500, 0), MovementCommand::CENTRED);
        let full = sticks(1000, -1000, 1000, 1000);
        assert_eq!(
            (full.pitch, full.roll, full.throttle, full.yaw),
            (AXIS_MAX, -AXIS_MAX, AXIS_MAX, AXIS_MAX)
        );
        assert_eq!(sticks(0, 0, 0, 0).throttle, -AXIS_MAX);
        let wild = sticks(i16::MAX, i16::MIN, i16::MAX, i16::MIN);
        assert_eq!(
            (wild.pitch, wild.roll, wild.throttle),
            (AXIS_MAX, -AXIS_MAX, AXIS_MAX)
        );
    }

    #[test]
    fn a_loop_that_does_not_take_loses_old_sticks_not_requests() {
        let feed = Feed::new("test".into());
        feed.heard(HostedEvent::Request);
        for _ in 0..200 {
            feed.heard(HostedEvent::Sticks(MovementCommand::CENTRED));
        }
        let events = feed.take();
        assert_eq!(events.len(), MAX_EVENTS);
        assert_eq!(events[0], HostedEvent::Request);
        assert!(feed.take().is_empty());
        feed.answered(true);
        feed.answered(false);
        assert_eq!(feed.take_answers(), vec![true, false]);
    }
}
