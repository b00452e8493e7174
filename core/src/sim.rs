//! Simulated devices for tests, benchmarks and the laptop demo: an output that records what it
//! was told, with time stamps, and an input that plays a script.

use crate::adapter::{Health, InputEvent, InputSource, OutputAdapter, OutputKind, OutputSpec};
use crate::arbiter::Setpoint;
use crate::error::LinkError;
use crate::time::MonoTime;
use std::collections::VecDeque;

/// What the simulated output was told.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SimAction {
    /// Drive with these values.
    Apply(Setpoint),
    /// Go safe.
    SafeState,
}

/// One recorded output.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SimRecord {
    /// When.
    pub at: MonoTime,
    /// What.
    pub action: SimAction,
}

/// `[output] adapter = "sim"`: the recording output, for tests, demos and benchmarks.
#[derive(Debug, Clone, Copy)]
pub struct Sim;

/// `[output] adapter = "sim"` takes no other keys.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimSettings {}

impl OutputKind for Sim {
    const NAME: &'static str = "sim";
    const SUMMARY: &'static str = "Records outputs in memory, for tests, demos and benchmarks \
        (`--record` writes them out).";
    type Settings = SimSettings;

    fn validate(_: &mut SimSettings) -> crate::Result<Box<dyn OutputSpec>> {
        Ok(Box::new(Sim))
    }
}

impl OutputSpec for Sim {
    fn open(&self, now: MonoTime) -> Result<Box<dyn OutputAdapter>, LinkError> {
        let mut sim = SimOutput::default();
        sim.safe_state(now)?;
        Ok(Box::new(sim))
    }

    fn clone_spec(&self) -> Box<dyn OutputSpec> {
        Box::new(*self)
    }
}

/// An output adapter that records every call, keeping the most recent `capacity` records
/// (older ones are counted in [`SimOutput::dropped`]) so a long benchmark cannot exhaust memory.
#[derive(Debug, Clone)]
pub struct SimOutput {
    records: VecDeque<SimRecord>,
    capacity: usize,
    dropped: u64,
    failure: Option<LinkError>,
}

impl Default for SimOutput {
    /// Keeps 100 000 records: over half an hour at 50 Hz, a few MB.
    fn default() -> Self {
        SimOutput::with_capacity(100_000)
    }
}

impl SimOutput {
    /// A recorder keeping at most `capacity` records (at least 1).
    pub fn with_capacity(capacity: usize) -> Self {
        SimOutput {
            records: VecDeque::new(),
            capacity: capacity.max(1),
            dropped: 0,
            failure: None,
        }
    }

    /// Recorded calls, oldest first.
    pub fn records(&self) -> impl Iterator<Item = &SimRecord> {
        self.records.iter()
    }

    /// The most recent record.
    pub fn last(&self) -> Option<&SimRecord> {
        self.records.back()
    }

    /// Records discarded because the buffer was full.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// Makes every following call fail with `error` (a simulated link loss) until
    /// [`SimOutput::restore`]. Failed calls are not recorded.
    pub fn fail_with(&mut self, error: LinkError) {
        self.failure = Some(error);
    }

    /// Ends a simulated failure.
    pub fn restore(&mut self) {
        self.failure = None;
    }

    fn record(&mut self, at: MonoTime, action: SimAction) -> Result<(), LinkError> {
        if let Some(e) = &self.failure {
            return Err(e.clone());
        }
        if self.records.len() == self.capacity {
            self.records.pop_front();
            self.dropped += 1;
        }
        self.records.push_back(SimRecord { at, action });
        Ok(())
    }
}

impl OutputAdapter for SimOutput {
    fn describe(&self) -> String {
        "sim (records outputs in memory)".into()
    }

    fn apply(&mut self, now: MonoTime, setpoint: &Setpoint) -> Result<(), LinkError> {
        self.record(now, SimAction::Apply(*setpoint))
    }

    fn safe_state(&mut self, now: MonoTime) -> Result<(), LinkError> {
        self.record(now, SimAction::SafeState)
    }

    fn health(&self) -> Health {
        match &self.failure {
            None => Health::Ok,
            Some(e) => Health::Down(e.detail.clone()),
        }
    }
}

/// An input source that plays `(time, event)` pairs: each event becomes due at its time.
#[derive(Debug, Clone, Default)]
pub struct ScriptedInput {
    script: VecDeque<(MonoTime, InputEvent)>,
}

impl ScriptedInput {
    /// A source playing `script`; it is sorted by time (stable, so equal times keep their order).
    pub fn new(mut script: Vec<(MonoTime, InputEvent)>) -> Self {
        script.sort_by_key(|(t, _)| *t);
        ScriptedInput {
            script: script.into(),
        }
    }

    /// Events not yet played.
    pub fn remaining(&self) -> usize {
        self.script.len()
    }
}

impl InputSource for ScriptedInput {
    fn describe(&self) -> String {
        format!("script ({} events)", self.script.len())
    }

    fn poll(&mut self, now: MonoTime) -> Result<Option<InputEvent>, LinkError> {
        match self.script.front() {
            Some((at, _)) if *at <= now => Ok(self.script.pop_front().map(|(_, e)| e)),
            _ => Ok(None),
        }
    }

    fn next_deadline(&self) -> Option<MonoTime> {
        self.script.front().map(|(t, _)| *t)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::adapter::InputAction;
    use crate::msg::{Mode, MovementCommand};

    fn setpoint(throttle: i16) -> Setpoint {
        Setpoint {
            movement: MovementCommand {
                throttle,
                ..MovementCommand::CENTRED
            },
            mode: Mode::Manual,
        }
    }

    #[test]
    fn records_calls_in_order_with_times() {
        let mut out = SimOutput::default();
        out.safe_state(MonoTime::from_millis(1)).expect("ok");
        out.apply(MonoTime::from_millis(2), &setpoint(5))
            .expect("ok");
        let got: Vec<_> = out.records().copied().collect();
        assert_eq!(
            got,
            [
                SimRecord {
                    at: MonoTime::from_millis(1),
                    action: SimAction::SafeState
                },
                SimRecord {
                    at: MonoTime::from_millis(2),
                    action: SimAction::Apply(setpoint(5))
                },
            ]
        );
    }

    #[test]
    fn keeps_only_the_newest_records_and_counts_the_rest() {
        let mut out = SimOutput::with_capacity(2);
        for i in 0..5 {
            out.apply(MonoTime::from_millis(i), &setpoint(i as i16))
                .expect("ok");
        }
        assert_eq!(out.dropped(), 3);
        assert_eq!(out.records().count(), 2);
        assert_eq!(out.last().map(|r| r.at), Some(MonoTime::from_millis(4)));
    }

    #[test]
    fn simulated_failure_reports_down_and_records_nothing() {
        let mut out = SimOutput::default();
        out.fail_with(LinkError::transient("sim: unplugged"));
        assert!(out.safe_state(MonoTime::ZERO).is_err());
        assert_eq!(out.health(), Health::Down("sim: unplugged".into()));
        assert_eq!(out.records().count(), 0);
        out.restore();
        assert!(out.safe_state(MonoTime::ZERO).is_ok());
        assert_eq!(out.health(), Health::Ok);
    }

    #[test]
    fn script_plays_events_when_due() {
        let mut input = ScriptedInput::new(vec![
            (MonoTime::from_millis(20), InputEvent::Deadman(false)),
            (MonoTime::from_millis(10), InputEvent::Deadman(true)),
            (
                MonoTime::from_millis(20),
                InputEvent::Action(InputAction::Release),
            ),
        ]);
        assert_eq!(input.next_deadline(), Some(MonoTime::from_millis(10)));
        assert_eq!(input.poll(MonoTime::from_millis(9)), Ok(None));
        assert_eq!(
            input.poll(MonoTime::from_millis(25)),
            Ok(Some(InputEvent::Deadman(true)))
        );
        assert_eq!(
            input.poll(MonoTime::from_millis(25)),
            Ok(Some(InputEvent::Deadman(false)))
        );
        assert_eq!(
            input.poll(MonoTime::from_millis(25)),
            Ok(Some(InputEvent::Action(InputAction::Release)))
        );
        assert_eq!(input.poll(MonoTime::from_millis(25)), Ok(None));
        assert_eq!(input.remaining(), 0);
    }
}
