//! The PWM device interface ([`PwmBackend`]) and the recording [`SimBackend`]; the backend a
//! config names is built by [`crate::open_backend`].
//!
//! A backend owns one set of channels, indexed `0..n` in config order, all at one period. It
//! turns pulse widths (µs) into whatever its device wants (ns duty cycles for sysfs, `Duration`s
//! for rppal), prepares a channel on first use, and retries that preparation on the next write
//! after a failure. It never panics on any pulse value: out-of-range values are reported.

use crate::config::{ChannelAddress, PwmVehicleConfig};
use rove_core::MonoTime;
use rove_core::error::LinkError;
use std::collections::VecDeque;
use std::sync::{Arc, Mutex, MutexGuard};

/// One set of PWM channels on one device.
pub trait PwmBackend {
    /// A one-line description naming the device (for logs and errors).
    fn describe(&self) -> String;

    /// Number of channels.
    fn channel_count(&self) -> usize;

    /// Sets channel `channel` to a pulse of `pulse_us` µs every period, preparing the channel
    /// first if it is not yet (or no longer) prepared.
    ///
    /// # Errors
    /// A classified [`LinkError`] naming the device path or pin when the channel index is out
    /// of range, the pulse is not shorter than the period, or the device write failed.
    fn set_pulse_us(
        &mut self,
        now: MonoTime,
        channel: usize,
        pulse_us: u16,
    ) -> Result<(), LinkError>;
}

impl<B: PwmBackend + ?Sized> PwmBackend for Box<B> {
    fn describe(&self) -> String {
        (**self).describe()
    }

    fn channel_count(&self) -> usize {
        (**self).channel_count()
    }

    fn set_pulse_us(
        &mut self,
        now: MonoTime,
        channel: usize,
        pulse_us: u16,
    ) -> Result<(), LinkError> {
        (**self).set_pulse_us(now, channel, pulse_us)
    }
}

/// One pulse the sim backend was told to output.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PulseRecord {
    /// When.
    pub at: MonoTime,
    /// Channel index (config order).
    pub channel: usize,
    /// Pulse width, µs.
    pub pulse_us: u16,
}

#[derive(Debug)]
struct SimState {
    records: VecDeque<PulseRecord>,
    capacity: usize,
    dropped: u64,
    failure: Option<LinkError>,
}

/// A shared handle on a [`SimBackend`]'s record: clone it before handing the backend to a
/// vehicle, then read what was written (or inject failures) from the test.
///
/// The lock is a `std::sync::Mutex`: every critical section is a few field updates with no
/// blocking inside, and the backend is driven from synchronous code.
#[derive(Debug, Clone)]
pub struct SimLog(Arc<Mutex<SimState>>);

impl SimLog {
    fn lock(&self) -> MutexGuard<'_, SimState> {
        // A panic while holding this lock cannot leave the record inconsistent (each update is
        // a single push/pop), so a poisoned lock is still safe to use.
        self.0.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Every kept record, oldest first.
    pub fn records(&self) -> Vec<PulseRecord> {
        self.lock().records.iter().copied().collect()
    }

    /// The most recent pulse of each channel of `count` channels (`None`: never written).
    pub fn latest(&self, count: usize) -> Vec<Option<u16>> {
        let mut out = vec![None; count];
        for r in self.lock().records.iter() {
            if let Some(slot) = out.get_mut(r.channel) {
                *slot = Some(r.pulse_us);
            }
        }
        out
    }

    /// Records discarded because the buffer was full.
    pub fn dropped(&self) -> u64 {
        self.lock().dropped
    }

    /// Forgets every record.
    pub fn clear(&self) {
        self.lock().records.clear();
    }

    /// Makes every following write fail with `error` (a simulated device loss) until
    /// [`SimLog::restore`]. Failed writes are not recorded.
    pub fn fail_with(&self, error: LinkError) {
        self.lock().failure = Some(error);
    }

    /// Ends a simulated failure.
    pub fn restore(&self) {
        self.lock().failure = None;
    }
}

/// Default sim capacity: 100 000 pulses, over 6 minutes of 4 channels at 50 Hz, a few MB.
pub const SIM_DEFAULT_CAPACITY: usize = 100_000;

/// A backend that records every `(time, channel, µs)` in a bounded buffer (the oldest records
/// are dropped and counted), for tests, benchmarks and the laptop demo.
#[derive(Debug)]
pub struct SimBackend {
    log: SimLog,
    addresses: Vec<ChannelAddress>,
    period_us: u64,
}

impl SimBackend {
    /// A sim with `addresses` (one per channel), `period_us`, keeping at most `capacity`
    /// records (at least 1).
    pub fn new(addresses: Vec<ChannelAddress>, period_us: u64, capacity: usize) -> Self {
        SimBackend {
            log: SimLog(Arc::new(Mutex::new(SimState {
                records: VecDeque::new(),
                capacity: capacity.max(1),
                dropped: 0,
                failure: None,
            }))),
            addresses,
            period_us,
        }
    }

    /// A sim with `config`'s channels and period and [`SIM_DEFAULT_CAPACITY`].
    pub fn for_config(config: &PwmVehicleConfig) -> Self {
        let period_us = u64::try_from(config.period.as_micros()).unwrap_or(u64::MAX);
        SimBackend::new(config.addresses(), period_us, SIM_DEFAULT_CAPACITY)
    }

    /// The shared record.
    pub fn log(&self) -> SimLog {
        self.log.clone()
    }
}

impl PwmBackend for SimBackend {
    fn describe(&self) -> String {
        format!(
            "sim PWM ({} channels, {} µs period, recorded in memory)",
            self.addresses.len(),
            self.period_us
        )
    }

    fn channel_count(&self) -> usize {
        self.addresses.len()
    }

    fn set_pulse_us(
        &mut self,
        now: MonoTime,
        channel: usize,
        pulse_us: u16,
    ) -> Result<(), LinkError> {
        if channel >= self.addresses.len() {
            return Err(LinkError::fatal(format!(
                "sim PWM: channel index {channel} out of range (have {})",
                self.addresses.len()
            )));
        }
        if u64::from(pulse_us) >= self.period_us {
            return Err(LinkError::fatal(format!(
                "sim PWM channel {channel}: pulse {pulse_us} µs is not shorter than the period \
                 ({} µs)",
                self.period_us
            )));
        }
        let mut state = self.log.lock();
        if let Some(e) = &state.failure {
            return Err(e.clone());
        }
        if state.records.len() == state.capacity {
            state.records.pop_front();
            state.dropped += 1;
        }
        state.records.push_back(PulseRecord {
            at: now,
            channel,
            pulse_us,
        });
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sim_records_and_bounds_its_buffer() {
        let mut sim = SimBackend::new(vec![ChannelAddress::Unaddressed; 2], 20_000, 3);
        let log = sim.log();
        for (i, us) in [1000u16, 1100, 1200, 1300].iter().enumerate() {
            sim.set_pulse_us(MonoTime::from_millis(i as u64), i % 2, *us)
                .expect("ok");
        }
        assert_eq!(log.dropped(), 1);
        assert_eq!(
            log.records(),
            [
                PulseRecord {
                    at: MonoTime::from_millis(1),
                    channel: 1,
                    pulse_us: 1100
                },
                PulseRecord {
                    at: MonoTime::from_millis(2),
                    channel: 0,
                    pulse_us: 1200
                },
                PulseRecord {
                    at: MonoTime::from_millis(3),
                    channel: 1,
                    pulse_us: 1300
                },
            ]
        );
        assert_eq!(log.latest(3), [Some(1200), Some(1300), None]);
    }

    #[test]
    fn sim_rejects_bad_channel_and_overlong_pulse_and_simulates_failure() {
        let mut sim = SimBackend::new(vec![ChannelAddress::Unaddressed], 2_500, 10);
        let log = sim.log();
        assert!(sim.set_pulse_us(MonoTime::ZERO, 1, 1500).is_err());
        assert!(sim.set_pulse_us(MonoTime::ZERO, 0, 2500).is_err());
        log.fail_with(LinkError::transient("sim: unplugged"));
        assert_eq!(
            sim.set_pulse_us(MonoTime::ZERO, 0, 1500),
            Err(LinkError::transient("sim: unplugged"))
        );
        log.restore();
        assert!(sim.set_pulse_us(MonoTime::ZERO, 0, 1500).is_ok());
        assert_eq!(log.records().len(), 1);
    }

    #[cfg(not(feature = "rppal"))]
    #[test]
    fn rppal_without_the_feature_is_a_fatal_error_saying_so() {
        let mut cfg: crate::PwmVehicleSettings = toml::from_str(
            "backend = \"rppal\"\n[[channels]]\nname = \"a\"\nsource = \"roll\"\npin = 18",
        )
        .expect("parses");
        let cfg = cfg.validate().expect("valid");
        let err = crate::open_backend(&cfg)
            .err()
            .expect("no rppal in this build");
        assert_eq!(err.disposition, rove_core::error::Disposition::Fatal);
        assert!(err.detail.contains("`rppal` feature"), "{err}");
    }
}
