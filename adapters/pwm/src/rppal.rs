//! The Raspberry Pi backend (cargo feature `rppal`): hardware PWM channels (`pwm_channel = 0|1`,
//! needs the `pwm` or `pwm-2chan` overlay in `config.txt`) and software PWM on any GPIO
//! (`pin = BCM number`), via the rppal crate.
//!
//! Each channel is opened at its first write and reopened at the next write after a failure.
//! Software PWM is timed by a thread of rppal's and jitters by tens of µs under load: fine for
//! an ESC or a steering servo, marginal for a flight controller (use hardware PWM or sysfs).

use crate::backend::PwmBackend;
use crate::config::{ChannelAddress, Polarity, PwmVehicleConfig};
use rove_core::MonoTime;
use rove_core::error::LinkError;
use rppal::gpio::{Gpio, OutputPin};
use rppal::pwm::{self, Pwm};
use std::time::Duration;

/// An opened channel.
#[derive(Debug)]
enum Output {
    /// Not opened yet, or closed after a failure.
    Closed,
    /// Software PWM on a GPIO pin.
    Pin(OutputPin),
    /// A hardware PWM channel.
    Hardware(Pwm),
}

#[derive(Debug)]
struct RppalChannel {
    address: ChannelAddress,
    polarity: Option<Polarity>,
    output: Output,
}

/// Raspberry Pi PWM outputs through rppal.
#[derive(Debug)]
pub struct RppalBackend {
    period: Duration,
    channels: Vec<RppalChannel>,
}

impl RppalBackend {
    /// A backend for `config`'s channels; nothing is opened until the first write.
    ///
    /// # Errors
    /// A fatal [`LinkError`] if a channel is not addressed by `pin` or `pwm_channel`.
    pub fn new(config: &PwmVehicleConfig) -> Result<Self, LinkError> {
        let mut channels = Vec::new();
        for c in &config.channels {
            match c.address {
                ChannelAddress::GpioPin(_) | ChannelAddress::HardwarePwm(_) => {}
                other => {
                    return Err(LinkError::fatal(format!(
                        "rppal PWM: channel {:?} is wired to {other}; give `pin` or `pwm_channel`",
                        c.name.as_str()
                    )));
                }
            }
            channels.push(RppalChannel {
                address: c.address,
                polarity: c.polarity,
                output: Output::Closed,
            });
        }
        Ok(RppalBackend {
            period: config.period,
            channels,
        })
    }
}

fn open(ch: &RppalChannel, period: Duration, pulse: Duration) -> Result<Output, String> {
    match ch.address {
        ChannelAddress::GpioPin(pin) => {
            let gpio = Gpio::new().map_err(|e| e.to_string())?;
            let mut out = gpio.get(pin).map_err(|e| e.to_string())?.into_output_low();
            out.set_pwm(period, pulse).map_err(|e| e.to_string())?;
            Ok(Output::Pin(out))
        }
        ChannelAddress::HardwarePwm(n) => {
            let channel = match n {
                0 => pwm::Channel::Pwm0,
                1 => pwm::Channel::Pwm1,
                other => return Err(format!("no hardware PWM channel {other}")),
            };
            let polarity = match ch.polarity {
                Some(Polarity::Inversed) => pwm::Polarity::Inverse,
                _ => pwm::Polarity::Normal,
            };
            let mut out = Pwm::with_period(channel, period, pulse, polarity, true)
                .map_err(|e| e.to_string())?;
            // Keep the last pulse (the safe state the vehicle writes on drop) on the pin after
            // exit, as sysfs does, rather than cut the signal.
            out.set_reset_on_drop(false);
            Ok(Output::Hardware(out))
        }
        other => Err(format!("{other} is not a Raspberry Pi output")),
    }
}

impl PwmBackend for RppalBackend {
    fn describe(&self) -> String {
        let names: Vec<String> = self
            .channels
            .iter()
            .map(|c| c.address.to_string())
            .collect();
        format!(
            "Raspberry Pi PWM via rppal ({}; {} µs period)",
            names.join(", "),
            self.period.as_micros()
        )
    }

    fn channel_count(&self) -> usize {
        self.channels.len()
    }

    fn set_pulse_us(
        &mut self,
        _now: MonoTime,
        channel: usize,
        pulse_us: u16,
    ) -> Result<(), LinkError> {
        let period = self.period;
        let Some(ch) = self.channels.get_mut(channel) else {
            return Err(LinkError::fatal(format!(
                "rppal PWM: channel index {channel} out of range"
            )));
        };
        let pulse = Duration::from_micros(u64::from(pulse_us));
        if pulse >= period {
            return Err(LinkError::fatal(format!(
                "rppal PWM {}: pulse {pulse_us} µs is not shorter than the period",
                ch.address
            )));
        }
        let result = match &mut ch.output {
            Output::Closed => open(ch, period, pulse).map(|o| ch.output = o),
            Output::Pin(out) => out.set_pwm(period, pulse).map_err(|e| e.to_string()),
            Output::Hardware(out) => out.set_pulse_width(pulse).map_err(|e| e.to_string()),
        };
        result.map_err(|e| {
            ch.output = Output::Closed;
            // rppal's errors do not expose a kind; permission and missing-overlay problems
            // come back on every retry, which the status makes visible. Transient keeps the
            // vehicle retrying (and in failsafe) rather than giving up on a channel.
            LinkError::transient(format!("rppal PWM {}: {e}", ch.address))
        })
    }
}
