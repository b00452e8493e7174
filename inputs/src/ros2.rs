//! [`Ros2Source`]: a ROS 2 teleop node as an operator's input. It reads `sensor_msgs/Joy`
//! (the standard `joy` node) or a twist (`teleop_twist_keyboard`) on its own ROS 2 participant
//! and feeds the [`Mapper`] as a joystick would, so the axis and button vocabulary is evdev's:
//! Joy axis i is `EV_ABS` code i (`ABS_X`, `ABS_Y`, `ABS_Z`, `ABS_RX`, …) on −1..1, button j
//! is `BTN_TRIGGER` + j; a twist's linear x, y, z and angular x, y, z are axes 0 to 5 (`ABS_X`
//! … `ABS_RZ`), as fractions of `max_linear` / `max_angular`. The first message connects the
//! "device"; silence for `silence_timeout_ms` (500 ms unless set) loses it, as an unplugged
//! joystick, and the next message connects it again.

use crate::codes::{EV_ABS, EV_KEY, RawEvent};
use crate::config::{MappingConfig, Ros2Message, SourceConfig};
use crate::curve::AbsState;
use crate::mapper::{DeviceEvent, InputStatus, LinkState, Mapper};
use rove_core::adapter::{InputEvent, InputSource};
use rove_core::error::LinkError;
use rove_core::time::MonoTime;
use rove_ros2::msg::{Joy, RosType, Twist, TwistStamped};
use rustdds::QosPolicyBuilder;
use rustdds::no_key::DataReaderCdr;
use rustdds::policy::{Durability, History, Reliability};
use std::time::Duration;

/// How often the source looks for new messages: the operator polls it at this period.
pub const POLL: Duration = Duration::from_millis(5);

/// Joy axes are −1..1 floats; as an absolute axis they span ±this.
const AXIS_SPAN: i32 = 32_767;

/// `BTN_TRIGGER`, the first joystick button code.
const BTN_TRIGGER: u16 = 0x120;

/// Most axes and buttons taken from one message (a message claiming more is cut).
const MAX_CONTROLS: usize = 64;

/// What the source reads.
enum Reader {
    Joy(DataReaderCdr<Joy>),
    Twist(DataReaderCdr<Twist>, [f64; 2]),
    Stamped(DataReaderCdr<TwistStamped>, [f64; 2]),
}

impl Reader {
    /// The next message as a Joy (a twist: its six components as axes, no buttons).
    fn take(&mut self) -> Result<Option<Joy>, ()> {
        let axes = |t: &Twist, [linear, angular]: [f64; 2]| {
            let (l, a) = (&t.linear, &t.angular);
            [
                l.x / linear,
                l.y / linear,
                l.z / linear,
                a.x / angular,
                a.y / angular,
                a.z / angular,
            ]
            .map(|v| v as f32)
            .to_vec()
        };
        let joy = |axes| Joy {
            axes,
            ..Joy::default()
        };
        match self {
            Reader::Joy(r) => r.take_next_sample().map(|s| s.map(|s| s.into_value())),
            Reader::Twist(r, max) => {
                (r.take_next_sample()).map(|s| s.map(|s| joy(axes(&s.into_value(), *max))))
            }
            Reader::Stamped(r, max) => {
                (r.take_next_sample()).map(|s| s.map(|s| joy(axes(&s.into_value().twist, *max))))
            }
        }
        .map_err(|_| ())
    }
}

/// The ROS 2 teleop source.
pub struct Ros2Source {
    mapper: Mapper,
    reader: Reader,
    message: Ros2Message,
    topic: String,
    /// Axes and buttons as last fed, once connected.
    last: Option<(Vec<i32>, Vec<bool>)>,
    polled: Option<MonoTime>,
    // Dropped last: its reader above goes first.
    _participant: rustdds::DomainParticipant,
}

impl std::fmt::Debug for Ros2Source {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Ros2Source")
            .field("topic", &self.topic)
            .finish_non_exhaustive()
    }
}

impl Ros2Source {
    /// Joins the ROS 2 graph and subscribes to the Joy topic `config` names.
    ///
    /// # Errors
    /// The source is not `ros2`, or rustdds cannot join or subscribe (fatal).
    pub fn open(source: &SourceConfig, mapping: MappingConfig) -> Result<Ros2Source, LinkError> {
        let SourceConfig::Ros2 {
            topic,
            message,
            max_linear,
            max_angular,
            domain_id,
            interfaces,
        } = source
        else {
            return Err(LinkError::fatal("not a ROS 2 source"));
        };
        let participant = rove_ros2::join(*domain_id, interfaces)?;
        // Best effort matches reliable and best-effort publishers alike; a Joy superseded by
        // the next is not worth a resend.
        let qos = QosPolicyBuilder::new()
            .reliability(Reliability::BestEffort)
            .durability(Durability::Volatile)
            .history(History::KeepLast { depth: 16 })
            .build();
        let max = [*max_linear, *max_angular];
        let (p, name) = (&participant, topic.as_str());
        let reader = match message {
            Ros2Message::Joy => Reader::Joy(rove_ros2::reader(p, name, qos)?),
            Ros2Message::Twist => Reader::Twist(rove_ros2::reader(p, name, qos)?, max),
            Ros2Message::TwistStamped => Reader::Stamped(rove_ros2::reader(p, name, qos)?, max),
        };
        let label = format!("ROS 2 {topic}");
        Ok(Ros2Source {
            mapper: Mapper::new(mapping, label),
            reader,
            message: *message,
            topic: topic.clone(),
            last: None,
            polled: None,
            _participant: participant,
        })
    }

    /// The mapper's status (link state, mapped values, buttons).
    pub fn status(&self) -> InputStatus {
        self.mapper.status()
    }

    /// Feeds one message: at the first (or the first after silence) the device connects with
    /// its state; after that, the axes and buttons that changed, then a frame end.
    fn feed(&mut self, now: MonoTime, joy: &Joy) {
        let axes: Vec<i32> = (joy.axes.iter().take(MAX_CONTROLS))
            .map(|a| {
                let a = if a.is_finite() {
                    a.clamp(-1.0, 1.0)
                } else {
                    0.0
                };
                (f64::from(a) * f64::from(AXIS_SPAN)).round() as i32
            })
            .collect();
        let buttons: Vec<bool> = (joy.buttons.iter().take(MAX_CONTROLS))
            .map(|b| *b != 0)
            .collect();
        let lost = matches!(self.mapper.status().link, LinkState::Lost { .. });
        let Some((old_axes, old_buttons)) = self.last.as_ref().filter(|_| !lost) else {
            self.mapper.feed(
                now,
                DeviceEvent::Connected {
                    name: format!("ROS 2 {}", self.topic),
                },
            );
            for (code, value) in (0u16..).zip(&axes) {
                let state = AbsState {
                    value: *value,
                    minimum: -AXIS_SPAN,
                    maximum: AXIS_SPAN,
                    fuzz: 0,
                    flat: 0,
                };
                self.mapper.feed(now, DeviceEvent::AbsState { code, state });
            }
            for (j, pressed) in (0u16..).zip(&buttons) {
                let code = BTN_TRIGGER + j;
                let pressed = *pressed;
                self.mapper
                    .feed(now, DeviceEvent::KeyState { code, pressed });
            }
            self.mapper
                .feed(now, DeviceEvent::Raw(RawEvent::syn_report()));
            self.last = Some((axes, buttons));
            return;
        };
        let mut events = Vec::new();
        for (code, value) in (0u16..).zip(&axes) {
            if old_axes.get(usize::from(code)) != Some(value) {
                events.push(RawEvent::new(EV_ABS, code, *value));
            }
        }
        for (j, pressed) in (0u16..).zip(&buttons) {
            if old_buttons.get(usize::from(j)) != Some(pressed) {
                events.push(RawEvent::new(EV_KEY, BTN_TRIGGER + j, i32::from(*pressed)));
            }
        }
        // Every message is a frame, also one that changed nothing: it says the node lives.
        events.push(RawEvent::syn_report());
        for event in events {
            self.mapper.feed(now, DeviceEvent::Raw(event));
        }
        self.last = Some((axes, buttons));
    }
}

impl InputSource for Ros2Source {
    fn describe(&self) -> String {
        let kind = match self.message {
            Ros2Message::Joy => Joy::ROS_NAME,
            Ros2Message::Twist => Twist::ROS_NAME,
            Ros2Message::TwistStamped => TwistStamped::ROS_NAME,
        };
        format!("ROS 2 {kind} on {}", self.topic)
    }

    fn poll(&mut self, now: MonoTime) -> Result<Option<InputEvent>, LinkError> {
        self.polled = Some(now);
        // Bounded per poll: a flood waits for the next one.
        for _ in 0..256 {
            match self.reader.take() {
                Ok(Some(joy)) => self.feed(now, &joy),
                Ok(None) => break,
                // A malformed sample is skipped: the next message counts.
                Err(_) => continue,
            }
        }
        self.mapper.tick(now);
        Ok(self.mapper.pop())
    }

    fn next_deadline(&self) -> Option<MonoTime> {
        let next = self.polled.map_or(MonoTime::ZERO, |t| t + POLL);
        Some(self.mapper.next_deadline().map_or(next, |m| m.min(next)))
    }
}
