//! [`NazaVehicle`]: the Naza-M output — a [`PwmVehicle`] plus a small state machine for the
//! combination stick command (CSC) and the land failsafe, stepped with injected time.
//!
//! States ([`NazaState`]):
//! - `Driving`: `apply` maps the setpoint; throttle slew limited (no jump on a change of
//!   hands).
//! - `Failsafe { since }`: hover values (sticks and throttle centred, U at ATTI or GPS), or with
//!   the land policy the throttle ramping from centre to the floor, measured from `since`.
//!   Entered at construction and by `safe_state`; left by the next `apply`.
//! - `Csc { command, until, resume }`: sticks held in the CSC corners, throttle at minimum,
//!   until `until`; `apply` is recorded but not output; `safe_state` aborts it. Then back to
//!   `resume`: Driving (sticks centred, throttle from minimum, ramping up under the slew
//!   limit with the next setpoints) or Failsafe (its values again).

use crate::config::{FailsafeThrottle, NazaConfig};
use crate::error::{NazaError, Result};
use rove_core::MonoTime;
use rove_core::adapter::{Health, OutputAdapter};
use rove_core::arbiter::Setpoint;
use rove_core::error::LinkError;
use rove_core::msg::{Mode, MovementCommand};
use rove_pwm::{PwmBackend, PwmVehicle};
use std::time::Duration;

/// How often the state machine wants [`OutputAdapter::keepalive`]: one 50 Hz PWM frame, so the
/// land ramp moves in steps no coarser than the signal can show.
pub const TICK_PERIOD: Duration = Duration::from_millis(20);

/// Which motor command a CSC was sent for (the Naza toggles; this is the operator's intent,
/// for status).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MotorCommand {
    /// Start the motors.
    Start,
    /// Stop the motors.
    Stop,
}

/// Where a CSC returns to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Resume {
    /// Driving with setpoints.
    Driving,
    /// The failsafe (restarted when the CSC ends).
    Failsafe,
}

/// The Naza output's state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NazaState {
    /// Setpoints are output.
    Driving,
    /// Failsafe values since `since`.
    Failsafe {
        /// When the failsafe began (the land ramp starts here).
        since: MonoTime,
    },
    /// A CSC is being held.
    Csc {
        /// For what.
        command: MotorCommand,
        /// When the sticks are released.
        until: MonoTime,
        /// What follows.
        resume: Resume,
    },
}

/// A DJI Naza-M on PWM backend `B`.
#[derive(Debug)]
pub struct NazaVehicle<B: PwmBackend> {
    pwm: PwmVehicle<B>,
    config: NazaConfig,
    state: NazaState,
    /// The mode of the latest setpoint (the failsafe mode before any): the U level kept during
    /// a CSC.
    mode: Mode,
}

impl<B: PwmBackend> NazaVehicle<B> {
    /// Writes the failsafe (hover values; the land ramp starts at `now`), then returns.
    ///
    /// # Errors
    /// As [`PwmVehicle::new`].
    pub fn new(config: NazaConfig, backend: B, now: MonoTime) -> Result<Self, LinkError> {
        let pwm = PwmVehicle::new(config.pwm.clone(), backend, now)?;
        Ok(NazaVehicle {
            pwm,
            mode: config.failsafe_mode,
            config,
            state: NazaState::Failsafe { since: now },
        })
    }

    /// The current state.
    pub fn state(&self) -> NazaState {
        self.state
    }

    /// The generic PWM vehicle underneath (for its config and backend).
    pub fn pwm(&self) -> &PwmVehicle<B> {
        &self.pwm
    }

    /// When the state machine next needs a [`NazaVehicle::tick`] without outside input: the
    /// CSC's end, or the next land-ramp step while the ramp is running.
    pub fn next_deadline(&self, now: MonoTime) -> Option<MonoTime> {
        match (self.state, self.config.failsafe_throttle) {
            (NazaState::Csc { until, .. }, _) => Some(until),
            (NazaState::Failsafe { since }, FailsafeThrottle::Land { ramp, .. })
                if now < since + ramp =>
            {
                Some(now + TICK_PERIOD)
            }
            _ => None,
        }
    }

    /// Sends the CSC to start the motors: sticks to the configured corners with the throttle
    /// at minimum, held for `csc_hold_ms`, then released (see the module doc).
    ///
    /// # Errors
    /// [`NazaError::CscInProgress`] while a CSC is held; [`NazaError::Link`] if the write
    /// failed (the CSC is then not in progress; the caller may retry).
    pub fn start_motors(&mut self, now: MonoTime) -> Result<()> {
        self.csc(now, MotorCommand::Start)
    }

    /// Sends the CSC to stop the motors (the same stick command; the Naza toggles).
    ///
    /// # Errors
    /// As [`NazaVehicle::start_motors`].
    pub fn stop_motors(&mut self, now: MonoTime) -> Result<()> {
        self.csc(now, MotorCommand::Stop)
    }

    fn csc(&mut self, now: MonoTime, command: MotorCommand) -> Result<()> {
        let resume = match self.state {
            NazaState::Csc { until, .. } => return Err(NazaError::CscInProgress { until }),
            NazaState::Driving => Resume::Driving,
            NazaState::Failsafe { .. } => Resume::Failsafe,
        };
        let pulses = self.pwm.target_pulses(&Setpoint {
            movement: self.config.csc.into(),
            mode: self.mode,
        });
        self.pwm.write_unlimited(now, &pulses)?;
        self.state = NazaState::Csc {
            command,
            until: now + self.config.csc_hold,
            resume,
        };
        Ok(())
    }

    /// Advances time-driven states: ends a CSC whose hold is over, moves the land ramp.
    ///
    /// # Errors
    /// A [`LinkError`] if a write failed.
    pub fn tick(&mut self, now: MonoTime) -> Result<(), LinkError> {
        match self.state {
            NazaState::Csc { until, resume, .. } if now >= until => match resume {
                Resume::Driving => {
                    self.state = NazaState::Driving;
                    // Sticks centred, throttle left at minimum: the next setpoints ramp it up
                    // under the slew limit instead of jumping to wherever the operator is.
                    let pulses = self.pwm.target_pulses(&Setpoint {
                        movement: MovementCommand {
                            throttle: -i16::MAX,
                            ..MovementCommand::CENTRED
                        },
                        mode: self.mode,
                    });
                    self.pwm.write_unlimited(now, &pulses)
                }
                Resume::Failsafe => {
                    self.state = NazaState::Failsafe { since: now };
                    self.write_failsafe(now)
                }
            },
            NazaState::Failsafe { .. } => match self.config.failsafe_throttle {
                FailsafeThrottle::Land { .. } => self.write_failsafe(now),
                FailsafeThrottle::Hover => Ok(()),
            },
            _ => Ok(()),
        }
    }

    /// The throttle pulse of the land ramp at `now`.
    fn land_throttle(&self, now: MonoTime, since: MonoTime, floor_us: u16, ramp: Duration) -> u16 {
        let centre = self.pwm.failsafe_pulses()[NazaConfig::THROTTLE];
        let elapsed = now.saturating_since(since).as_secs_f64();
        let progress = (elapsed / ramp.as_secs_f64().max(f64::EPSILON)).clamp(0.0, 1.0);
        let pulse = f64::from(centre) - progress * (f64::from(centre) - f64::from(floor_us));
        pulse.round() as u16
    }

    fn write_failsafe(&mut self, now: MonoTime) -> Result<(), LinkError> {
        let since = match self.state {
            NazaState::Failsafe { since } => since,
            _ => now,
        };
        let mut pulses = self.pwm.failsafe_pulses();
        if let FailsafeThrottle::Land { floor_us, ramp } = self.config.failsafe_throttle {
            pulses[NazaConfig::THROTTLE] = self.land_throttle(now, since, floor_us, ramp);
        }
        self.pwm.write_unlimited(now, &pulses)
    }
}

impl<B: PwmBackend> OutputAdapter for NazaVehicle<B> {
    fn describe(&self) -> String {
        format!("DJI Naza-M (A/E/T/R/U) on {}", self.pwm.describe())
    }

    fn apply(&mut self, now: MonoTime, setpoint: &Setpoint) -> Result<(), LinkError> {
        self.mode = setpoint.mode;
        match self.state {
            NazaState::Csc { until, .. } if now < until => {
                // The CSC is being held: the setpoint waits. Keep the U level current.
                let pulses = self.pwm.target_pulses(&Setpoint {
                    movement: self.config.csc.into(),
                    mode: self.mode,
                });
                self.pwm.write_unlimited(now, &pulses)
            }
            NazaState::Csc { .. } => {
                self.tick(now)?;
                self.state = NazaState::Driving;
                self.pwm.apply(now, setpoint)
            }
            NazaState::Driving | NazaState::Failsafe { .. } => {
                self.state = NazaState::Driving;
                self.pwm.apply(now, setpoint)
            }
        }
    }

    fn safe_state(&mut self, now: MonoTime) -> Result<(), LinkError> {
        // A failsafe already running keeps its start, so a repeated safe state does not
        // restart the land ramp; anything else (driving, a CSC) starts it now.
        if !matches!(self.state, NazaState::Failsafe { .. }) {
            self.state = NazaState::Failsafe { since: now };
        }
        self.write_failsafe(now)
    }

    fn keepalive_period(&self) -> Option<Duration> {
        Some(TICK_PERIOD)
    }

    fn keepalive(&mut self, now: MonoTime) -> Result<(), LinkError> {
        self.tick(now)
    }

    fn health(&self) -> Health {
        self.pwm.health()
    }
}
