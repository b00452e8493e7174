//! The config-defined PWM vehicle: every channel of a [`PwmVehicleConfig`] driven through its
//! map and slew limiter on one [`PwmBackend`].
//!
//! Safe state: written before [`PwmVehicle::new`] returns, on [`OutputAdapter::safe_state`],
//! and from `Drop`. It bypasses slew limiting and resets every limiter to the failsafe pulse, so
//! the next setpoint ramps from there.

use crate::backend::PwmBackend;
use crate::config::{ChannelSource, PwmVehicleConfig};
use rove_core::MonoTime;
use rove_core::adapter::{Health, OutputAdapter};
use rove_core::arbiter::Setpoint;
use rove_core::error::LinkError;
use rove_core::mapping::SlewLimiter;

/// A PWM vehicle on backend `B`.
#[derive(Debug)]
pub struct PwmVehicle<B: PwmBackend> {
    config: PwmVehicleConfig,
    backend: B,
    limiters: Vec<SlewLimiter>,
    health: Health,
    /// The latest `now` seen, for the safe-state write in `Drop` (which gets no time).
    last_now: MonoTime,
}

impl<B: PwmBackend> PwmVehicle<B> {
    /// Drives every channel to its failsafe pulse, then returns the vehicle.
    ///
    /// # Errors
    /// The first [`LinkError`] if the safe state could not be written to every channel (the
    /// backend is dropped; build a new one to retry), or a fatal error if the backend does not
    /// have one channel per configured channel.
    pub fn new(config: PwmVehicleConfig, backend: B, now: MonoTime) -> Result<Self, LinkError> {
        if backend.channel_count() != config.channels.len() {
            return Err(LinkError::fatal(format!(
                "{}: has {} channels, the config {}",
                backend.describe(),
                backend.channel_count(),
                config.channels.len()
            )));
        }
        let limiters = config
            .channels
            .iter()
            .map(|c| match c.source {
                ChannelSource::Axis(_, map) => map.slew_limiter(),
                _ => SlewLimiter::new(None),
            })
            .collect();
        let mut vehicle = PwmVehicle {
            config,
            backend,
            limiters,
            health: Health::Ok,
            last_now: now,
        };
        vehicle.safe_state(now)?;
        Ok(vehicle)
    }

    /// The validated config.
    pub fn config(&self) -> &PwmVehicleConfig {
        &self.config
    }

    /// The backend (for tests: a sysfs journal).
    pub fn backend(&self) -> &B {
        &self.backend
    }

    /// Every channel's pulse for `setpoint`, mapped but not slew limited.
    pub fn target_pulses(&self, setpoint: &Setpoint) -> Vec<u16> {
        self.config
            .channels
            .iter()
            .map(|c| match c.source {
                ChannelSource::Axis(axis, map) => map.map(axis.of(&setpoint.movement)),
                ChannelSource::Mode(levels) => levels.level(setpoint.mode),
                ChannelSource::Constant(us) => us,
            })
            .collect()
    }

    /// Every channel's failsafe pulse.
    pub fn failsafe_pulses(&self) -> Vec<u16> {
        self.config.channels.iter().map(|c| c.failsafe_us).collect()
    }

    /// Writes `targets` through each channel's slew limiter (what `apply` does).
    ///
    /// # Errors
    /// As [`PwmVehicle::write_unlimited`].
    pub fn write_limited(&mut self, now: MonoTime, targets: &[u16]) -> Result<(), LinkError> {
        let pulses: Vec<u16> = self
            .limiters
            .iter_mut()
            .zip(targets)
            .map(|(l, t)| l.step(now, *t))
            .collect();
        self.write_all(now, &pulses)
    }

    /// Writes `pulses` as they are, bypassing slew limits, and restarts every limiter from
    /// them (what `safe_state` does; presets use it for stick commands and failsafe ramps).
    ///
    /// # Errors
    /// The first channel's [`LinkError`] if any write failed (every channel is still tried, so
    /// one bad channel does not keep the others from their values), or a fatal error if
    /// `pulses` has the wrong length.
    pub fn write_unlimited(&mut self, now: MonoTime, pulses: &[u16]) -> Result<(), LinkError> {
        for (l, p) in self.limiters.iter_mut().zip(pulses) {
            l.reset(now, *p);
        }
        self.write_all(now, pulses)
    }

    fn write_all(&mut self, now: MonoTime, pulses: &[u16]) -> Result<(), LinkError> {
        self.last_now = self.last_now.max(now);
        if pulses.len() != self.config.channels.len() {
            let e = LinkError::fatal(format!(
                "{}: {} pulses for {} channels",
                self.backend.describe(),
                pulses.len(),
                self.config.channels.len()
            ));
            self.health = Health::Down(e.detail.clone());
            return Err(e);
        }
        let mut first_error = None;
        for (i, pulse) in pulses.iter().enumerate() {
            if let Err(e) = self.backend.set_pulse_us(now, i, *pulse) {
                first_error.get_or_insert(e);
            }
        }
        match first_error {
            None => {
                self.health = Health::Ok;
                Ok(())
            }
            Some(e) => {
                self.health = Health::Down(e.detail.clone());
                Err(e)
            }
        }
    }
}

impl<B: PwmBackend> OutputAdapter for PwmVehicle<B> {
    fn describe(&self) -> String {
        let names: Vec<&str> = self
            .config
            .channels
            .iter()
            .map(|c| c.name.as_str())
            .collect();
        format!(
            "pwm vehicle [{}] on {}",
            names.join(", "),
            self.backend.describe()
        )
    }

    fn apply(&mut self, now: MonoTime, setpoint: &Setpoint) -> Result<(), LinkError> {
        let targets = self.target_pulses(setpoint);
        self.write_limited(now, &targets)
    }

    fn safe_state(&mut self, now: MonoTime) -> Result<(), LinkError> {
        let pulses = self.failsafe_pulses();
        self.write_unlimited(now, &pulses)
    }

    fn health(&self) -> Health {
        self.health.clone()
    }
}

impl<B: PwmBackend> Drop for PwmVehicle<B> {
    fn drop(&mut self) {
        // Runs before the backend's own fields drop, so the failsafe pulse is on the pin when
        // (for sysfs) the process exits and the kernel keeps driving it. Errors have nowhere to
        // go from here; the gateway already logged the safe state it wrote on shutdown.
        let now = self.last_now;
        let _ = self.safe_state(now);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::backend::{PulseRecord, SimBackend, SimLog};
    use crate::config::PwmVehicleSettings;
    use rove_core::msg::{Mode, MovementCommand};
    use std::time::Duration;

    const CONFIG: &str = r#"
        backend = "sim"
        [[channels]]
        name = "steering"
        source = "roll"
        min_us = 1100
        max_us = 1900
        [[channels]]
        name = "throttle"
        source = "throttle"
        slew_us_per_s = 1000
        failsafe_us = 1400
        [[channels]]
        name = "U"
        source = "mode"
        [[channels]]
        name = "lights"
        source = "constant"
        value_us = 1800
    "#;

    fn vehicle() -> (PwmVehicle<SimBackend>, SimLog) {
        let cfg = toml::from_str::<PwmVehicleSettings>(CONFIG)
            .expect("parses")
            .validate()
            .expect("valid");
        let sim = SimBackend::for_config(&cfg);
        let log = sim.log();
        let v = PwmVehicle::new(cfg, sim, MonoTime::from_millis(5)).expect("starts");
        (v, log)
    }

    fn sp(roll: i16, throttle: i16, mode: Mode) -> Setpoint {
        Setpoint {
            movement: MovementCommand {
                roll,
                throttle,
                ..MovementCommand::CENTRED
            },
            mode,
        }
    }

    #[test]
    fn safe_state_is_written_before_new_returns() {
        let (_v, log) = vehicle();
        let at = MonoTime::from_millis(5);
        assert_eq!(
            log.records(),
            [
                PulseRecord {
                    at,
                    channel: 0,
                    pulse_us: 1500
                },
                PulseRecord {
                    at,
                    channel: 1,
                    pulse_us: 1400
                },
                PulseRecord {
                    at,
                    channel: 2,
                    pulse_us: 1500
                },
                PulseRecord {
                    at,
                    channel: 3,
                    pulse_us: 1800
                },
            ]
        );
    }

    #[test]
    fn apply_maps_each_source_and_slew_limits_throttle() {
        let (mut v, log) = vehicle();
        let t = MonoTime::from_millis(1005);
        v.apply(t, &sp(i16::MAX, i16::MAX, Mode::Auto)).expect("ok");
        // Throttle from 1400 toward 2000 at 1000 µs/s for 1 s: reaches 2000 (600 < 1000).
        assert_eq!(
            log.latest(4),
            [Some(1900), Some(2000), Some(2000), Some(1800)]
        );
        v.apply(
            t + Duration::from_millis(100),
            &sp(-i16::MAX, -i16::MAX, Mode::Manual),
        )
        .expect("ok");
        // 100 ms at 1000 µs/s: 100 µs down; steering has no limit.
        assert_eq!(
            log.latest(4),
            [Some(1100), Some(1900), Some(1000), Some(1800)]
        );
    }

    #[test]
    fn safe_state_bypasses_slew_and_restarts_the_limiter_there() {
        let (mut v, log) = vehicle();
        let t = MonoTime::from_millis(2000);
        v.apply(t, &sp(0, i16::MAX, Mode::Manual)).expect("ok");
        assert_eq!(log.latest(4)[1], Some(2000));
        v.safe_state(t + Duration::from_millis(1)).expect("ok");
        assert_eq!(
            log.latest(4),
            [Some(1500), Some(1400), Some(1500), Some(1800)]
        );
        // Next command ramps from the failsafe pulse, not from 2000.
        v.apply(
            t + Duration::from_millis(51),
            &sp(0, i16::MAX, Mode::Manual),
        )
        .expect("ok");
        assert_eq!(log.latest(4)[1], Some(1450));
    }

    #[test]
    fn health_goes_down_on_failure_and_back_up_on_success() {
        let (mut v, log) = vehicle();
        assert_eq!(v.health(), Health::Ok);
        log.fail_with(LinkError::transient("sim: unplugged"));
        let err = v
            .apply(MonoTime::from_millis(10), &sp(0, 0, Mode::Manual))
            .expect_err("fails");
        assert_eq!(err, LinkError::transient("sim: unplugged"));
        assert_eq!(v.health(), Health::Down("sim: unplugged".into()));
        log.restore();
        v.safe_state(MonoTime::from_millis(20)).expect("ok");
        assert_eq!(v.health(), Health::Ok);
    }

    #[test]
    fn drop_writes_the_safe_state_at_the_last_time_seen() {
        let (mut v, log) = vehicle();
        v.apply(
            MonoTime::from_millis(3000),
            &sp(i16::MAX, i16::MAX, Mode::Auto),
        )
        .expect("ok");
        log.clear();
        drop(v);
        let recs = log.records();
        assert_eq!(recs.len(), 4);
        assert!(recs.iter().all(|r| r.at == MonoTime::from_millis(3000)));
        assert_eq!(
            log.latest(4),
            [Some(1500), Some(1400), Some(1500), Some(1800)]
        );
    }

    #[test]
    fn a_failing_start_is_an_error_and_wrong_lengths_never_panic() {
        let cfg = toml::from_str::<PwmVehicleSettings>(CONFIG)
            .expect("parses")
            .validate()
            .expect("valid");
        let sim = SimBackend::for_config(&cfg);
        sim.log().fail_with(LinkError::fatal("sim: no device"));
        assert_eq!(
            PwmVehicle::new(cfg.clone(), sim, MonoTime::ZERO).err(),
            Some(LinkError::fatal("sim: no device"))
        );
        let short = SimBackend::new(vec![], 20_000, 10);
        assert!(PwmVehicle::new(cfg, short, MonoTime::ZERO).is_err());
        let (mut v, _log) = vehicle();
        assert!(v.write_unlimited(MonoTime::ZERO, &[1500]).is_err());
        assert!(matches!(v.health(), Health::Down(_)));
    }

    #[test]
    fn extreme_inputs_stay_in_range() {
        let (mut v, log) = vehicle();
        for (i, x) in [i16::MIN, -1, 0, 1, i16::MAX].iter().enumerate() {
            let t = MonoTime::from_millis(10_000 + 1_000 * i as u64);
            v.apply(t, &sp(*x, *x, Mode::Assisted)).expect("ok");
            let latest = log.latest(4);
            let steer = latest[0].expect("written");
            assert!((1100..=1900).contains(&steer), "{steer}");
        }
        assert_eq!(log.latest(4)[0], Some(1900));
    }
}
