//! The end of a frame and the axis values: control edges (actions, deadman), key-ramp targets,
//! each axis's value through calibration and shaping, the no-jump rest check, and the `Axes`
//! output.

use super::{Link, Mapper, REST_TOLERANCE};
use crate::codes::Control;
use crate::config::{AXES, AxisConfig, AxisInput, Rest};
use crate::curve::{Calibration, Shaping, to_axis};
use rove_core::adapter::InputEvent;
use rove_core::mapping::Axis;
use rove_core::msg::MovementCommand;

impl Mapper {
    /// Ends a frame: control edges, ramp targets, axes.
    pub(super) fn evaluate(&mut self, fire: bool) {
        let mut actions = Vec::new();
        let mut deadman_pressed = false;
        if let Some(deadman) = self.mapping.deadman {
            let (was, now) = self.control_edge(deadman);
            if was && !now && self.deadman_held {
                self.deadman_held = false;
                self.last_emitted = None;
                self.push(InputEvent::Deadman(false));
            }
            if !was && now && fire && !self.deadman_held {
                deadman_pressed = true;
            }
        }
        for i in 0..self.mapping.actions.len() {
            let (control, action) = self.mapping.actions[i];
            let (was, now) = self.control_edge(control);
            if !was && now && fire {
                actions.push(action);
            }
        }
        for action in actions {
            self.push(InputEvent::Action(action));
        }
        if deadman_pressed {
            self.deadman_held = true;
            self.last_emitted = None;
            self.push(InputEvent::Deadman(true));
        }
        for (slot, axis) in self.mapping.axes.iter().enumerate() {
            if let (
                Some(AxisConfig {
                    input:
                        AxisInput::Keys {
                            negative, positive, ..
                        },
                    ..
                }),
                Some(ramp),
            ) = (axis, &mut self.ramps[slot])
            {
                let held = |k: &Option<u16>| {
                    k.is_some_and(|k| self.keys.contains(&k) && !self.stale_keys.contains(&k))
                };
                ramp.set_keys(held(negative), held(positive));
            }
        }
        self.update_axes();
    }

    /// Updates a bound control's recorded state; returns (before, now).
    fn control_edge(&mut self, control: Control) -> (bool, bool) {
        let now = self.control_state(control);
        let was = self.controls.insert(control, now).unwrap_or(false);
        (was, now)
    }

    fn control_state(&self, control: Control) -> bool {
        let direction = |code: u16| -> Option<f64> {
            let value = *self.abs.get(&code)?;
            // Without absinfo (a bare recording) the sign of the raw value decides, which is
            // right for hats (−1/0/+1).
            Some(
                match Calibration::resolve(self.absinfo.get(&code), None, None, None) {
                    Some(cal) => cal.normalise(value),
                    None => f64::from(value.signum()),
                },
            )
        };
        match control {
            Control::Key(code) => self.keys.contains(&code),
            Control::AbsPositive(code) => direction(code).is_some_and(|x| x > 0.5),
            Control::AbsNegative(code) => direction(code).is_some_and(|x| x < -0.5),
        }
    }

    /// An axis's value before expo and scale (for the rest check) and after (the output),
    /// both −1..1; `None` while its value or calibration is unknown.
    fn axis_value(&self, slot: usize) -> Option<(f64, f64)> {
        let config = self.mapping.axes[slot]?;
        let x = match config.input {
            AxisInput::Abs {
                code,
                min,
                centre,
                max,
                deadzone,
            } => {
                let raw = *self.abs.get(&code)?;
                let info = self.absinfo.get(&code);
                let cal = Calibration::resolve(info, min, centre, max)?;
                let deadzone =
                    deadzone.unwrap_or_else(|| cal.flat_fraction(info.map_or(0, |i| i.flat)));
                let shaping = Shaping {
                    invert: config.reverse,
                    deadzone,
                    expo: 0.0,
                    scale: 1.0,
                };
                shaping.apply(cal.normalise(raw))
            }
            AxisInput::Keys { .. } => {
                let ramp = self.ramps[slot]?;
                Shaping {
                    invert: config.reverse,
                    ..Shaping::default()
                }
                .apply(ramp.value())
            }
        };
        let shaped = Shaping {
            invert: false,
            deadzone: 0.0,
            expo: config.expo,
            scale: config.scale,
        }
        .apply(x);
        Some((x, shaped))
    }

    pub(super) fn sticks(&self) -> MovementCommand {
        let v = |slot: usize| self.axis_value(slot).map_or(0, |(_, y)| to_axis(y));
        MovementCommand {
            throttle: v(0),
            roll: v(1),
            pitch: v(2),
            yaw: v(3),
        }
    }

    pub(super) fn axes_not_at_rest(&self) -> Vec<Axis> {
        AXES.iter()
            .enumerate()
            .filter(|(slot, _)| !self.at_rest(*slot))
            .map(|(_, a)| *a)
            .collect()
    }

    fn at_rest(&self, slot: usize) -> bool {
        let Some(config) = self.mapping.axes[slot] else {
            return true;
        };
        if let AxisInput::Keys {
            negative, positive, ..
        } = config.input
            && [negative, positive]
                .iter()
                .flatten()
                .any(|k| self.keys.contains(k))
        {
            return false;
        }
        let Some((x, _)) = self.axis_value(slot) else {
            return false;
        };
        match config.rest {
            Rest::Centre => x.abs() <= REST_TOLERANCE,
            Rest::Low => x <= -1.0 + REST_TOLERANCE,
            Rest::High => x >= 1.0 - REST_TOLERANCE,
        }
    }

    pub(super) fn update_axes(&mut self) {
        match self.link {
            Link::Lost(..) => return,
            Link::AwaitingRest => {
                if (0..AXES.len()).all(|slot| self.at_rest(slot)) {
                    self.link = Link::Live;
                    self.last_emitted = None;
                } else {
                    return;
                }
            }
            Link::Live => {}
        }
        if self.mapping.deadman.is_some() && !self.deadman_held {
            return;
        }
        let sticks = self.sticks();
        if self.last_emitted != Some(sticks) {
            self.last_emitted = Some(sticks);
            self.push(InputEvent::Axes(sticks));
        }
    }
}
