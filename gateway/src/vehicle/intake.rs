//! ControlCommand samples into arbiter events.

use crate::dds::{self, Domain, KeyedControlCommand};
use crate::runtime::RateLimited;
use rove_core::arbiter::{Event, ParticipantId};
use rove_core::freshness::Freshness;
use rove_core::msg::DeviceId;
use rustdds::with_key::Sample;
use std::collections::HashMap;
use std::time::Duration;

/// Command writers whose delivery baselines are remembered (rove_core::freshness).
pub(super) const MAX_WRITERS: usize = 1024;

/// Most ControlCommand samples taken in one turn of the loop.
pub(super) const MAX_BATCH: usize = 256;

/// ControlCommand samples into arbiter events: each writer's strength (from discovery), and
/// which samples are fresh. Of a batch taken at once, a writer's Movement sample supersedes its
/// earlier ones (a control stream needs the newest command, not every one), and a sample that
/// queued up longer than the command timeout (`rove_core::freshness`) is dropped and counted.
pub(super) struct Intake {
    me: DeviceId,
    strengths: HashMap<rustdds::GUID, rove_core::hierarchy::Strength>,
    freshness: Freshness,
    stale: RateLimited,
    stale_total: u64,
    unknown_strength: RateLimited,
    malformed: RateLimited,
}

impl Intake {
    pub(super) fn new(me: DeviceId, command_timeout: Duration) -> Intake {
        Intake {
            me,
            strengths: HashMap::new(),
            freshness: Freshness::new(command_timeout, MAX_WRITERS),
            stale: RateLimited::new(
                "stale ControlCommand sample (it queued up longer than the command timeout)",
            ),
            stale_total: 0,
            unknown_strength: RateLimited::new(
                "ControlCommand from a writer whose ownership strength is unknown",
            ),
            malformed: RateLimited::new("malformed or unreadable ControlCommand sample"),
        }
    }

    /// Remembers a writer's strength; beyond [`MAX_WRITERS`] writers it is looked up in
    /// discovery each time instead (a flood of writers cannot grow the table).
    pub(super) fn learn(
        &mut self,
        writer: rustdds::GUID,
        strength: rove_core::hierarchy::Strength,
    ) {
        if self.strengths.len() < MAX_WRITERS || self.strengths.contains_key(&writer) {
            self.strengths.insert(writer, strength);
        }
    }

    /// Forgets a writer; whether its strength was known (it was a command writer).
    pub(super) fn forget(&mut self, writer: rustdds::GUID) -> bool {
        self.freshness.forget(dds::writer_id(writer));
        self.strengths.remove(&writer).is_some()
    }

    /// Forgets every writer of a participant that left (issue 51: only writer losses were,
    /// and a participant whose endpoint disposals never came left its writers here).
    pub(super) fn forget_participant(&mut self, participant: ParticipantId) {
        self.freshness.forget_participant(participant);
        self.strengths
            .retain(|&w, _| dds::writer_id(w).participant != participant);
    }

    /// Whether a command writer of `participant` is known.
    pub(super) fn drives_from(&self, participant: ParticipantId) -> bool {
        (self.strengths.keys()).any(|&w| dds::writer_id(w).participant == participant)
    }

    /// The events of a batch of samples, in order.
    pub(super) fn events(
        &mut self,
        domain: &Domain,
        clock: &crate::runtime::Clock,
        batch: Vec<rustdds::dds::ReadResult<rustdds::with_key::DataSample<KeyedControlCommand>>>,
    ) -> Vec<Event> {
        let samples: Vec<_> = (batch.into_iter())
            .filter_map(|r| r.map_err(|e| self.malformed.warn(&e)).ok())
            .collect();
        // A Movement sample carries the whole setpoint: it supersedes every earlier sample of
        // its writer (a Probe or a Mode change does not).
        let superseded = |i: usize, writer: rustdds::GUID| {
            samples[i + 1..].iter().any(|later| {
                later.sample_info().writer_guid() == writer
                    && matches!(later.value(), Sample::Value(c)
                        if c.0.command_type == rove_core::msg::CommandType::Movement)
            })
        };
        let mut events = Vec::new();
        for (i, sample) in samples.iter().enumerate() {
            let guid = sample.sample_info().writer_guid();
            let writer = dds::writer_id(guid);
            let sent = sample
                .sample_info()
                .source_timestamp()
                .map(dds::timestamp_nanos);
            match sample.value() {
                Sample::Value(_) if superseded(i, guid) => {}
                Sample::Value(cmd) => {
                    if let Some(late) = self.freshness.judge(writer, sent, clock.now()) {
                        self.stale_total += 1;
                        let total = self.stale_total;
                        self.stale.warn(&format_args!(
                            "from {writer}, {late:?} late; {total} in all"
                        ));
                        continue;
                    }
                    let strength = match self.strengths.get(&guid) {
                        Some(s) => Some(*s),
                        None => {
                            let s = domain.discovered_strength(guid);
                            if let Some(s) = s {
                                self.learn(guid, s);
                            }
                            s
                        }
                    };
                    match strength {
                        Some(strength) => events.push(Event::Sample {
                            writer,
                            strength,
                            command: cmd.0,
                            arrival: clock.now(),
                        }),
                        None => self.unknown_strength.warn(&writer),
                    }
                }
                Sample::Dispose(key) if *key == self.me => events.push(Event::Released { writer }),
                Sample::Dispose(_) => {}
            }
        }
        events
    }
}
