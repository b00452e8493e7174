//! What the mapper shows users: [`InputStatus`], a snapshot for status displays and `rove
//! inputs show`, with its [`LinkState`].

use crate::codes::{abs_name, key_name};
use rove_core::mapping::Axis;
use rove_core::msg::MovementCommand;
use std::fmt;

/// The link state as shown to users.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LinkState {
    /// Sticks drive the output (subject to the deadman).
    Live,
    /// Waiting for these axes to reach their rest position (the no-jump rule): "centre the
    /// sticks".
    AwaitingRest {
        /// Axes not yet at rest.
        axes: Vec<Axis>,
    },
    /// No usable input.
    Lost {
        /// Why.
        reason: String,
    },
}

/// A snapshot for status displays and `rove inputs show`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct InputStatus {
    /// The device's name, once connected.
    pub device: Option<String>,
    /// Live, awaiting rest, or lost.
    pub link: LinkState,
    /// `Some(held)` when a deadman is configured.
    pub deadman: Option<bool>,
    /// The mapped stick values, whatever the link and deadman (what the sticks say).
    pub sticks: MovementCommand,
    /// What the source reports: `sticks` while live and the deadman is held, else neutral.
    pub output: MovementCommand,
    /// Every absolute axis seen, raw value by code (to find codes when writing a mapping).
    pub abs: Vec<(u16, i32)>,
    /// Every key and button held, by code.
    pub pressed: Vec<u16>,
}

impl fmt::Display for InputStatus {
    /// One line: `throttle=… roll=… pitch=… yaw=… deadman=held live | ABS_X=… | BTN_SOUTH …`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = &self.sticks;
        write!(
            f,
            "throttle={:6} roll={:6} pitch={:6} yaw={:6}",
            s.throttle, s.roll, s.pitch, s.yaw
        )?;
        match self.deadman {
            Some(true) => f.write_str(" deadman=held")?,
            Some(false) => f.write_str(" deadman=up")?,
            None => {}
        }
        match &self.link {
            LinkState::Live => f.write_str(" live")?,
            LinkState::AwaitingRest { axes } => {
                let names: Vec<_> = axes.iter().map(|a| a.name()).collect();
                write!(f, " centre: {}", names.join(","))?;
            }
            LinkState::Lost { reason } => write!(f, " LOST: {reason}")?,
        }
        f.write_str(" |")?;
        for (code, value) in &self.abs {
            write!(f, " {}={value}", abs_name(*code))?;
        }
        f.write_str(" |")?;
        for code in &self.pressed {
            write!(f, " {}", key_name(*code))?;
        }
        Ok(())
    }
}
