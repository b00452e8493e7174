//! [`CanSettings::validate`]: the section's own keys (interface, FD, rate), the frames and the
//! DroneCAN table in turn, our DroneCAN identifiers kept from raw frames; and the checks every
//! output shares: send rates and the four scale values.

use super::frames::validate_frame;
use super::{
    CanConfig, CanSettings, DEFAULT_RATE_HZ, INTERFACE_NAME_MAX, RATE_RANGE_HZ, ScaleSettings,
};
use crate::bus::CanId;
use crate::dronecan::{self, ARRAY_COMMAND, NODE_STATUS, NODE_STATUS_PRIORITY, RAW_COMMAND};
use crate::scale::Scale;
use rove_core::config::{Int, Unique};
use rove_core::error::ConfigErrors;
use std::fmt;
use std::ops::RangeInclusive;
use std::time::Duration;

impl CanSettings {
    /// Validates every key, filling defaults into `self` (which then serializes as the
    /// effective config).
    ///
    /// # Errors
    /// [`rove_core::Error::Config`] listing every key that breaks a rule of the crate docs'
    /// key table (or repeats an identifier, name or place), relative to `[output]`.
    pub fn validate(&mut self) -> rove_core::Result<CanConfig> {
        let mut errors = ConfigErrors::default();
        let mut names = Unique::default();
        let fd = *self.fd.get_or_insert(false);
        let interface = (errors.required("interface", &self.interface)).unwrap_or_default();
        let bad = |c: char| !c.is_ascii_graphic() || c == '/' || c == ':';
        let fits = (1..=INTERFACE_NAME_MAX).contains(&interface.len());
        if self.interface.is_some() && (!fits || interface.contains(bad)) {
            let max = INTERFACE_NAME_MAX;
            let rule = format!(
                "must be a network interface name: 1..={max} printable characters, no '/' or ':'"
            );
            errors.add("interface", format!("{interface:?}"), rule);
        }
        let rate = check_rate(&mut self.rate_hz, DEFAULT_RATE_HZ, &mut errors);
        let (mut frames, mut ids) = (Vec::new(), Unique::default());
        for (i, f) in self.frames.iter_mut().enumerate() {
            let frame = errors.within(&format!("frames[{i}]"), |fe| {
                validate_frame(f, i, fd, rate, (&mut names, &mut ids), fe)
            });
            frames.extend(frame);
        }
        let dronecan = (self.dronecan.as_mut())
            .and_then(|d| errors.within("dronecan", |de| d.validate(rate, &mut names, de)));
        if let Some(dc) = &dronecan {
            // Our own DroneCAN identifiers must not be reused by a raw frame (the first is named).
            let ours = [
                (ARRAY_COMMAND, dc.priority),
                (RAW_COMMAND, dc.priority),
                (NODE_STATUS, NODE_STATUS_PRIORITY),
            ];
            for (t, priority) in ours {
                let id = CanId::Extended(dronecan::message_id(priority, t.id, dc.node_id));
                if let Some(frame) = ids.claim(id, "dronecan") {
                    let rule = format!("must differ from our DroneCAN {} identifier", t.name);
                    errors.add(format!("{frame}.id"), id, rule);
                }
            }
        }
        if self.frames.is_empty() && self.dronecan.is_none() {
            let rule =
                "a CAN vehicle needs at least one [[output.frames]] or an [output.dronecan] table";
            errors.add("frames", "[]", rule);
        }
        errors.into_result(CanConfig {
            interface,
            fd,
            frames,
            dronecan,
        })
    }
}

pub(super) fn period_of(rate_hz: i64) -> Duration {
    Duration::from_nanos(1_000_000_000 / rate_hz.clamp(1, 1_000_000_000) as u64)
}

/// A `rate_hz` key, filled with `default` when absent; `default` also stands in for a bad one.
pub(super) fn check_rate(rate: &mut Option<Int>, default: Int, errors: &mut ConfigErrors) -> Int {
    let rate = *rate.get_or_insert(default);
    (errors.int("rate_hz", rate, RATE_RANGE_HZ, " Hz")).unwrap_or(default)
}

impl<T: Copy + PartialOrd + fmt::Display> ScaleSettings<T> {
    /// Checks the four values (min and max in either order) against `range`, filling
    /// defaults: `(lo, hi)` for min and max, `mid` for the centre, then `failsafe_default` or
    /// the centre. `None` if any is invalid (each invalid key recorded with `rule`).
    pub(super) fn check(
        &mut self,
        (lo, hi): (T, T),
        mid: fn(T, T) -> T,
        failsafe_default: Option<T>,
        (range, rule): (RangeInclusive<T>, &str),
        errors: &mut ConfigErrors,
    ) -> Option<[T; 4]> {
        let (min, max) = (*self.min.get_or_insert(lo), *self.max.get_or_insert(hi));
        let centre = *self.centre.get_or_insert_with(|| mid(min, max));
        let failsafe = *self
            .failsafe
            .get_or_insert(failsafe_default.unwrap_or(centre));
        let values = [min, centre, max, failsafe];
        let mut ok = true;
        for (key, v) in ["min", "centre", "max", "failsafe"].into_iter().zip(values) {
            if !range.contains(&v) {
                errors.add(key, v, rule);
                ok = false;
            }
        }
        let between = (min < centre && centre < max) || (max < centre && centre < min);
        if ok && !between {
            let rule = format!("must lie strictly between min ({min}) and max ({max})");
            errors.add("centre", centre, rule);
            ok = false;
        }
        ok.then_some(values)
    }
}

/// [`ScaleSettings::check`] for integer device units: `lo..=hi` as the range and its rule.
pub(super) fn int_scale(
    s: &mut ScaleSettings<Int>,
    defaults: (Int, Int),
    failsafe_default: Option<Int>,
    (lo, hi): (Int, Int),
    errors: &mut ConfigErrors,
) -> Option<(Scale, Int)> {
    let rule = format!("must be {lo}..={hi}");
    // In i128: `a` and `b` are any numbers the file holds (checked against the range next).
    let mid = |a: Int, b: Int| {
        let mid = (i128::from(a) + i128::from(b)).div_euclid(2);
        Int::try_from(mid).unwrap_or(a)
    };
    let [min, centre, max, failsafe] =
        s.check(defaults, mid, failsafe_default, (lo..=hi, &rule), errors)?;
    Some((Scale { min, centre, max }, failsafe))
}
