//! How the arbiter records one event before it re-arbitrates: a sample (checked against the
//! vehicle, the trust tables and the source it comes from), a release, a writer or participant
//! leaving, a grant accepted or finished; and the source table's admission and eviction.

use super::{
    Arbiter, Controller, Decision, Event, Ignored, Presence, Setpoint, Source, WriterId,
    is_grant_stream,
};
use crate::hierarchy::Strength;
use crate::msg::{CommandType, ControlCommand, DeviceId, MovementCommand};
use crate::time::MonoTime;
use crate::trust::{Distrust, Suspect};
use crate::watchdog::Watchdog;

impl Arbiter {
    /// Records `event`; returns the writer whose new values may need applying.
    pub(super) fn record(
        &mut self,
        now: MonoTime,
        event: &Event,
        decision: &mut Decision,
    ) -> Option<WriterId> {
        let mut sampled = None;
        match *event {
            Event::Sample {
                writer,
                strength,
                command,
                arrival,
            } => match self.record_sample(now, writer, strength, &command, arrival.min(now)) {
                Ok(is_values) => {
                    if is_values {
                        sampled = Some(writer);
                    }
                    if strength == Strength::PRIORITY && self.grant != Some(command.src_id) {
                        decision.ignored = Some(Ignored::PriorityWithoutGrant);
                    }
                }
                Err(Rejected::Ignored(why)) => decision.ignored = Some(why),
                Err(Rejected::Suspect(suspect)) => decision.distrust(suspect),
            },
            Event::Released { writer } => match self.find(writer) {
                Some(i) => {
                    let s = &mut self.sources[i];
                    s.presence = Presence::Released;
                    s.watchdog.clear();
                    s.high_water = s.high_water.max(now);
                    if is_grant_stream(&s.controller, self.grant) {
                        // A holder that stops its priority stream is done with the grant.
                        self.grant = None;
                    }
                }
                None => decision.ignored = Some(Ignored::UnknownSource),
            },
            Event::WriterGone { writer } => {
                if !self.remove_where(|c| c.writer == writer) {
                    decision.ignored = Some(Ignored::UnknownSource);
                }
            }
            Event::ParticipantGone { participant } => {
                self.identities.participant_gone(now, participant);
                if !self.remove_where(|c| c.writer.participant == participant) {
                    decision.ignored = Some(Ignored::UnknownSource);
                }
            }
            Event::GrantAccepted {
                holder,
                granted_by,
                stamp,
                sender,
            } => {
                let trusted = (self.identities.check(now, granted_by, sender)).and_then(|()| {
                    self.access.allows(holder).map_err(|why| Suspect {
                        device: holder,
                        sender,
                        why,
                    })
                });
                match trusted {
                    Err(suspect) => decision.distrust(suspect),
                    Ok(()) => match self.accept_grant(now, holder, granted_by) {
                        Err(why) => decision.ignored = Some(why),
                        Ok(()) => self.grant_stamp = stamp,
                    },
                }
            }
            Event::GrantFinished {
                holder,
                stamp,
                sender,
            } => {
                // `>=`: rove echoes the grant's stamp; a foreign peer stamping its FINISH at
                // send time is later still.
                if let Err(suspect) = self.identities.check(now, holder, sender) {
                    decision.distrust(suspect);
                } else if self.grant == Some(holder) && stamp >= self.grant_stamp {
                    self.grant = None;
                } else {
                    decision.ignored = Some(Ignored::NotGrantHolder);
                }
            }
            Event::Heard { device, sender } => {
                if let Err(suspect) = self.identities.check(now, device, sender) {
                    decision.distrust(suspect);
                }
            }
            Event::Tick => {}
        }
        sampled
    }

    /// Records a sample. `Ok(true)` if it carried values (movement or mode), `Ok(false)` for a
    /// keep-alive.
    fn record_sample(
        &mut self,
        now: MonoTime,
        writer: WriterId,
        strength: Strength,
        command: &ControlCommand,
        arrival: MonoTime,
    ) -> Result<bool, Rejected> {
        if command.dest_id != self.vehicle {
            return Err(Ignored::NotForThisVehicle.into());
        }
        if command.src_id == self.vehicle {
            return Err(Ignored::FromThisVehicle.into());
        }
        if strength == Strength::FAILSAFE {
            return Err(Ignored::FailsafeStrength.into());
        }
        let suspect = |why| Suspect {
            device: command.src_id,
            sender: writer.participant,
            why,
        };
        (self.access)
            .check_strength(command.src_id, strength)
            .map_err(suspect)?;
        let level = (self.identities)
            .claim_level(now, command.src_id, writer.participant)
            .map_err(suspect)?;
        if let Some(level) = level
            && !self.access.within_level(strength, level)
        {
            return Err(suspect(Distrust::AboveSite {
                claimed: strength,
                level,
            })
            .into());
        }
        if now.saturating_since(arrival) >= self.config.command_timeout.get() {
            return Err(Ignored::Stale.into());
        }
        let index = match self.find(writer) {
            Some(i) => i,
            None => self.insert(now, writer, command.src_id, strength)?,
        };
        let source = &mut self.sources[index];
        if source.controller.device != command.src_id {
            return Err(Ignored::SourceMismatch.into());
        }
        if arrival < source.high_water {
            return Err(Ignored::OutOfOrder.into());
        }
        source.high_water = arrival;
        source.controller.strength = strength;
        source.presence = Presence::Streaming;
        source.watchdog.kick(arrival);
        let timeout = self.config.command_timeout;
        let values = match command.command_type {
            CommandType::Probe => return Ok(false),
            CommandType::Movement => Setpoint {
                movement: command.movement_command,
                mode: command.mode,
            },
            // A mode change keeps the current stick values, if they are still fresh.
            CommandType::Mode => Setpoint {
                movement: source
                    .fresh_setpoint(arrival, timeout)
                    .map_or(MovementCommand::CENTRED, |s| s.movement),
                mode: command.mode,
            },
        };
        source.setpoint = Some((arrival, values));
        Ok(true)
    }

    fn insert(
        &mut self,
        now: MonoTime,
        writer: WriterId,
        device: DeviceId,
        strength: Strength,
    ) -> Result<usize, Ignored> {
        let owner = self.owner.writer();
        let grant = self.grant;
        // Never evicted: the owner's stream, the grant holder's, and live ones (but below).
        let keep = |s: &Source| {
            s.is_live(now)
                || Some(s.controller.writer) == owner
                || is_grant_stream(&s.controller, grant)
        };
        let participant = writer.participant;
        let theirs = |s: &Source| s.controller.writer.participant == participant;
        if self.sources.iter().filter(|s| theirs(s)).count() >= self.config.per_participant {
            self.sources.retain(|s| !theirs(s) || keep(s));
            if self.sources.iter().filter(|s| theirs(s)).count() >= self.config.per_participant {
                return Err(Ignored::ParticipantQuota);
            }
        }
        if self.sources.len() >= self.config.max_sources {
            // Make room by forgetting silent streams. Only here, under a flood of writers, does
            // the arbiter forget a stream that has not left: a later release of a forgotten
            // stream is then unknown. The owner and the grant holder's streams are never evicted.
            self.sources.retain(keep);
        }
        if self.sources.len() >= self.config.max_sources {
            // The grant holder still gets in, in place of the weakest live stream that neither
            // owns nor holds the grant (a flood must not keep a granted operator out).
            let weakest = (self.sources.iter().enumerate())
                .filter(|(_, s)| Some(s.controller.writer) != owner)
                .filter(|(_, s)| !is_grant_stream(&s.controller, grant))
                .min_by_key(|(_, s)| s.controller.strength)
                .map(|(i, _)| i);
            match weakest {
                Some(i) if grant == Some(device) => {
                    self.sources.remove(i);
                }
                _ => return Err(Ignored::TooManySources),
            }
        }
        self.sources.push(Source {
            controller: Controller {
                writer,
                device,
                strength,
            },
            watchdog: Watchdog::new(self.config.command_timeout),
            presence: Presence::Streaming,
            high_water: MonoTime::ZERO,
            setpoint: None,
        });
        Ok(self.sources.len() - 1)
    }

    fn accept_grant(
        &mut self,
        now: MonoTime,
        holder: DeviceId,
        granted_by: DeviceId,
    ) -> Result<(), Ignored> {
        if holder == self.vehicle || holder == granted_by {
            return Err(Ignored::InvalidGrant);
        }
        let owner_consents = self.owner.device() == Some(granted_by);
        let just_stepped_down = self
            .stepped_down
            .is_some_and(|s| s.device == granted_by && now < s.until);
        if !(owner_consents || just_stepped_down) {
            return Err(Ignored::ConsentNotFromOwner);
        }
        self.grant = Some(holder);
        Ok(())
    }

    /// Removes matching sources; true if any was removed. A grant holder whose priority stream
    /// leaves is done with the grant.
    fn remove_where(&mut self, matches: impl Fn(&Controller) -> bool) -> bool {
        let before = self.sources.len();
        let grant = self.grant;
        let mut holder_left = false;
        self.sources.retain(|s| {
            let gone = matches(&s.controller);
            if gone && is_grant_stream(&s.controller, grant) {
                holder_left = true;
            }
            !gone
        });
        if holder_left {
            self.grant = None;
        }
        self.sources.len() != before
    }
}

/// Why a sample was not recorded.
enum Rejected {
    Ignored(Ignored),
    Suspect(Suspect),
}

impl From<Ignored> for Rejected {
    fn from(why: Ignored) -> Self {
        Rejected::Ignored(why)
    }
}

impl From<Suspect> for Rejected {
    fn from(suspect: Suspect) -> Self {
        Rejected::Suspect(suspect)
    }
}

impl Decision {
    fn distrust(&mut self, suspect: Suspect) {
        self.ignored = Some(Ignored::Untrusted);
        self.suspect = Some(suspect);
    }
}
