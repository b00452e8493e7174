//! The operator's `[input]` table: the raw serde structs ([`InputSettings`], which only parse and
//! reject unknown keys) and `validate()`, which checks every key, collects every problem and
//! returns the validated [`InputConfig`].
//!
//! Keys of errors are relative to the `[input]` table, e.g. `axes.throttle.deadband_pct`; the
//! gateway puts `input.` in front. The keys are listed in the crate README.
//!
//! # Layout
//! - this file: the tables, the validated types, every source but ROS 2's;
//! - `ros2.rs`: `source = "ros2"`'s keys.

use crate::codes::{Control, abs_name, parse_abs, parse_key};
use rove_core::adapter::InputAction;
use rove_core::config::{ABSENT, Int, Unique};
use rove_core::error::ConfigErrors;
use rove_core::mapping::{Axis, DEADBAND_RANGE_PCT, EXPO_RANGE};
use rove_core::msg::Mode;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Default time between attempts to reopen an unplugged device, ms. Half a second feels
/// immediate to an operator replugging a cable and costs one directory scan per attempt; much
/// shorter only burns CPU while nothing is plugged in.
pub const DEFAULT_REOPEN_INTERVAL_MS: Int = 500;

/// Accepted `reopen_interval_ms`.
pub const REOPEN_INTERVAL_RANGE_MS: std::ops::RangeInclusive<Int> = 10..=60_000;

/// Accepted `silence_timeout_ms`: from 50 ms (a few frames of a gamepad that streams at
/// 100–250 Hz) to 10 minutes.
pub const SILENCE_TIMEOUT_RANGE_MS: std::ops::RangeInclusive<Int> = 50..=600_000;

/// Default keyboard ramp-up time (0 → full scale), ms: a quarter second is quick enough to
/// steer and slow enough that a tap is a nudge, not a jerk.
pub const DEFAULT_RAMP_UP_MS: Int = 250;

/// Default keyboard spring-back time (full scale → 0), ms: faster than the ramp-up, because
/// letting go means "stop".
pub const DEFAULT_SPRING_BACK_MS: Int = 150;

/// Longest accepted ramp-up or spring-back, ms; beyond ten seconds a key axis is unusable.
pub const MAX_RAMP_MS: Int = 10_000;

mod ros2;
pub use ros2::DEFAULT_ROS2_SILENCE_MS;

rove_core::config_types! {
    /// Which kind of input `[input] source` selects.
    pub keyword SourceKind {
        Joystick => "An evdev joystick or gamepad (absent `device`/`name`: the first).",
        Keyboard => "An evdev keyboard (absent `device`/`name`: the first).",
        Replay => "A recorded event stream played from `file`.",
        Ros2 => "A ROS 2 `sensor_msgs/Joy` topic (the standard `joy` node): axis i is `EV_ABS` \
            code i (`ABS_X`, `ABS_Y`, `ABS_Z`, `ABS_RX`…), button j is `BTN_TRIGGER` + j.",
    }

    /// What a `ros2` source reads.
    pub keyword Ros2Message {
        #[serde(rename = "Joy")] Joy => "`sensor_msgs/msg/Joy`.",
        #[serde(rename = "Twist")] Twist => "`geometry_msgs/msg/Twist`.",
        #[serde(rename = "TwistStamped")] TwistStamped => "`geometry_msgs/msg/TwistStamped`.",
    }

    /// `[input]` as written.
    pub table InputSettings {
        source: Option<SourceKind> => "What to read.",
        device: Option<PathBuf> => "Joystick/keyboard: device path (by-id links are stable).",
        name: Option<String> => "Joystick/keyboard: name pattern, case-insensitive, `*` wildcard.",
        grab: Option<bool> => "Joystick/keyboard: take the device exclusively (EVIOCGRAB).",
        reopen_interval_ms: Option<Int> => "Joystick/keyboard: time between reopen attempts, ms.",
        file: Option<PathBuf> => "Replay: the recording to play.",
        topic: Option<String> => "ROS 2: the topic (absent: `/joy`, or `/cmd_vel` for a twist).",
        message: Option<Ros2Message> => "ROS 2: `\"Joy\"` (absent), `\"Twist\"` or \
            `\"TwistStamped\"` (`teleop_twist_keyboard`).",
        max_linear: Option<f64> => "ROS 2 twist: m/s that count as full stick (absent: 0.5, \
            teleop_twist_keyboard's default speed).",
        max_angular: Option<f64> => "ROS 2 twist: rad/s that count as full stick (absent: 1.0).",
        domain_id: Option<Int> => "ROS 2: the graph's DDS domain, `ROS_DOMAIN_ID` (absent: 0).",
        interfaces: Option<Vec<std::net::Ipv4Addr>> => "ROS 2: the interfaces the ROS 2 side \
            may use (absent: loopback only).",
        silence_timeout_ms: Option<Int> => "No event at all for this long → lost, ms.",
        #[serde(default)] axes: AxesSettings => "`[input.axes.*]`: what drives each movement axis.",
        #[serde(default)] buttons: ButtonSettings => "`[input.buttons]`: each action's control.",
    }

    /// `[input.axes]` as written: one optional table per movement axis.
    pub table AxesSettings {
        throttle: Option<AxisSettings> => "`[input.axes.throttle]`.",
        roll: Option<AxisSettings> => "`[input.axes.roll]` (UGV steering).",
        pitch: Option<AxisSettings> => "`[input.axes.pitch]`.",
        yaw: Option<AxisSettings> => "`[input.axes.yaw]`.",
    }

    /// Where an axis must rest before driving starts or resumes (the no-jump rule).
    #[derive(Default)]
    pub keyword Rest {
        #[default] Centre => "Within 5 % of centre (self-centring sticks, key axes).",
        Low => "Within 5 % of −full scale (a throttle lever at idle).",
        High => "Within 5 % of +full scale.",
    }

    /// One `[input.axes.NAME]` table as written: either an absolute axis (`abs` with calibration
    /// keys) or a pair of keys (`negative`/`positive` with ramp keys).
    pub table AxisSettings {
        abs: Option<String> => "The absolute axis, e.g. `\"ABS_Y\"`, `\"ABS_HAT0X\"`.",
        negative: Option<String> => "Key or button towards −full scale, e.g. `\"KEY_S\"`.",
        positive: Option<String> => "Key or button towards +full scale, e.g. `\"KEY_W\"`.",
        #[serde(alias = "invert")] reverse: Option<bool> => "Negate the axis.",
        #[serde(alias = "deadzone_pct")] deadband_pct: Option<f64> => "Abs: dead zone, \
            % of the half range.",
        expo: Option<f64> => "Expo 0..=1 (absent: 0, linear).",
        scale_pct: Option<f64> => "Output at full deflection, percent of full scale.",
        min: Option<Int> => "Abs: raw value at −full scale (absent: the device's minimum).",
        centre: Option<Int> => "Abs: raw value at centre (absent: midpoint of min and max).",
        max: Option<Int> => "Abs: raw value at +full scale (absent: the device's maximum).",
        ramp_up_ms: Option<Int> => "Keys: time from centre to full scale while held, ms.",
        spring_back_ms: Option<Int> => "Keys: time from full scale back to centre, ms.",
        rest: Option<Rest> => "Where the axis must be before driving resumes.",
    }

    /// `[input.buttons]` as written: action → control name (`"BTN_SOUTH"`, `"KEY_SPACE"`,
    /// `"ABS_HAT0Y-"`, `"ABS_Z+"`).
    pub table ButtonSettings {
        deadman: Option<String> => "Hold to drive; when set, axes are neutral unless it is held.",
        mode_manual: Option<String> => "Switch to MANUAL.",
        mode_assisted: Option<String> => "Switch to ASSISTED.",
        mode_auto: Option<String> => "Switch to AUTO.",
        request_control: Option<String> => "Ask the selected vehicle's owner for control.",
        accept: Option<String> => "Accept an incoming request.",
        refuse: Option<String> => "Refuse an incoming request.",
        finish: Option<String> => "Give a grant back.",
        release: Option<String> => "Stop driving the selected vehicle.",
        next_vehicle: Option<String> => "Select the next vehicle.",
        previous_vehicle: Option<String> => "Select the previous vehicle.",
    }

    /// How a device is chosen.
    #[derive(Debug, Clone, PartialEq, Eq)]
    pub enum DeviceSelector {
        Path => "A path (`/dev/input/eventN` or a by-id link), reopened by that path." (PathBuf),
        Name => "The first device whose name matches the pattern (`*` wildcard)." (String),
        AnyJoystick => "The first device with `ABS_X` and `ABS_Y` (a joystick or gamepad).",
        AnyKeyboard => "The first device that looks like a keyboard (has `KEY_A` … `KEY_Z`).",
    }
}

impl std::fmt::Display for DeviceSelector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DeviceSelector::Path(p) => write!(f, "{}", p.display()),
            DeviceSelector::Name(n) => write!(f, "name {n:?}"),
            DeviceSelector::AnyJoystick => f.write_str("first joystick"),
            DeviceSelector::AnyKeyboard => f.write_str("first keyboard"),
        }
    }
}

rove_core::config_types! {
    /// Validated source choice.
    #[derive(Debug, Clone, PartialEq)]
    pub enum SourceConfig {
        Evdev => "An evdev device." {
            selector: DeviceSelector => "Which device.",
            grab: bool => "Take it exclusively.",
            reopen_interval: Duration => "Time between reopen attempts.",
        },
        Replay => "A recording." {
            file: PathBuf => "The file (relative paths are relative to the process's working \
                directory unless [`InputConfig::resolve_relative_to`] was called).",
        },
        Ros2 => "A ROS 2 Joy or twist topic." {
            topic: String => "The topic (a ROS 2 name, `/joy`).",
            message: Ros2Message => "Joy, Twist or TwistStamped.",
            max_linear: f64 => "A twist's m/s at full stick.",
            max_angular: f64 => "A twist's rad/s at full stick.",
            domain_id: u16 => "The DDS domain.",
            interfaces: Vec<std::net::Ipv4Addr> => "The interfaces.",
        },
    }

    /// What drives a movement axis.
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub enum AxisInput {
        Abs => "An absolute axis with optional calibration overrides." {
            code: u16 => "`EV_ABS` code.",
            min: Option<i32> => "Raw value at −1 (absent: device minimum).",
            centre: Option<i32> => "Raw value at 0 (absent: midpoint).",
            max: Option<i32> => "Raw value at +1 (absent: device maximum).",
            deadzone: Option<f64> => "Dead zone as a fraction of the half range (absent: from the \
                device's `flat`).",
        },
        Keys => "Two keys with a ramp." {
            negative: Option<u16> => "`EV_KEY` code towards −1.",
            positive: Option<u16> => "`EV_KEY` code towards +1.",
            ramp_up: Duration => "Time for 0 → ±1.",
            spring_back: Duration => "Time for ±1 → 0.",
        },
    }

    /// A validated axis mapping.
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub struct AxisConfig {
        input: AxisInput => "The input.",
        reverse: bool => "Negate.",
        expo: f64 => "Expo 0..=1.",
        scale: f64 => "Full-deflection output, fraction 0..=1.",
        rest: Rest => "Resting position required by the no-jump rule.",
    }

    /// The validated mapping: axes, deadman, action buttons and silence timeout.
    #[derive(Debug, Clone, PartialEq, Default)]
    pub struct MappingConfig {
        axes: [Option<AxisConfig>; 4] => "Throttle, roll, pitch, yaw, in [`Axis`] order.",
        deadman: Option<Control> => "The hold-to-drive control.",
        actions: Vec<(Control, InputAction)> => "Action controls.",
        silence_timeout: Option<Duration> => "No events for this long → lost.",
    }

    /// A validated `[input]`: only this type crosses crate boundaries.
    #[derive(Debug, Clone, PartialEq)]
    pub struct InputConfig {
        kind: SourceKind => "The kind of source.",
        source: SourceConfig => "Device or recording.",
        mapping: MappingConfig => "The mapping.",
    }
}

/// The four axes in the order of [`MappingConfig::axes`].
pub const AXES: [Axis; 4] = [Axis::Throttle, Axis::Roll, Axis::Pitch, Axis::Yaw];

impl InputConfig {
    /// The same mapping read from another device (for `rove inputs show DEVICE`): the source
    /// becomes an evdev device chosen by `selector`, keeping `grab` and the reopen interval
    /// when the source already was a device.
    pub fn with_device(mut self, selector: DeviceSelector) -> Self {
        match &mut self.source {
            SourceConfig::Evdev { selector: s, .. } => *s = selector,
            SourceConfig::Replay { .. } | SourceConfig::Ros2 { .. } => {
                let reopen = Duration::from_millis(DEFAULT_REOPEN_INTERVAL_MS.unsigned_abs());
                self.kind = SourceKind::Joystick;
                self.source = SourceConfig::Evdev {
                    selector,
                    grab: false,
                    reopen_interval: reopen,
                };
            }
        }
        self
    }

    /// Makes a relative replay `file` or device path relative to `base` (the directory of the
    /// config file; `join` leaves an absolute one as it is), so a config works from anywhere.
    pub fn resolve_relative_to(&mut self, base: &Path) {
        if let SourceConfig::Replay { file: p }
        | SourceConfig::Evdev {
            selector: DeviceSelector::Path(p),
            ..
        } = &mut self.source
        {
            *p = base.join(&*p);
        }
    }
}

impl InputSettings {
    /// Validates, filling defaults; keys in errors are relative to `[input]`.
    ///
    /// # Errors
    /// [`rove_core::Error::Config`] listing every key that breaks a rule of the crate README's
    /// key list, does not apply to the source or axis kind, or uses a control used before.
    pub fn validate(&mut self) -> rove_core::Result<InputConfig> {
        self.validate_kind(None)
    }

    /// As [`InputSettings::validate`] for a known `kind`, for callers whose own tagged enum
    /// consumed the `source` key (serde's internally tagged enums remove the tag before the
    /// variant's struct sees the table). A `source` key that is present must agree.
    ///
    /// # Errors
    /// As [`InputSettings::validate`].
    pub fn validate_as(&mut self, kind: SourceKind) -> rove_core::Result<InputConfig> {
        self.validate_kind(Some(kind))
    }

    fn validate_kind(&mut self, expected: Option<SourceKind>) -> rove_core::Result<InputConfig> {
        let mut errors = ConfigErrors::default();
        let name = |k: SourceKind| format!("{k:?}").to_lowercase();
        let kind = match (self.source, expected) {
            (Some(s), Some(kind)) if s != kind => {
                errors.add("source", name(s), format!("must be {:?}", name(kind)));
                kind
            }
            (_, Some(kind)) | (Some(kind), None) => kind,
            (None, None) => {
                let rule = "must be one of \"joystick\", \"keyboard\", \"replay\", \"ros2\"";
                errors.absent("source", rule);
                SourceKind::Joystick
            }
        };
        let source = self.validate_source(kind, &mut errors);
        let rule = " ms (leave it out to turn silence detection off)";
        let silence = (self.silence_timeout_ms, SILENCE_TIMEOUT_RANGE_MS);
        let silence_timeout = errors.opt_int("silence_timeout_ms", silence.0, silence.1, rule);
        let silence_timeout = silence_timeout.map(Duration::from_millis);
        let mut mapping = MappingConfig {
            silence_timeout,
            ..MappingConfig::default()
        };
        // Who uses which control, for the "used twice" check: control → key path.
        let mut used = Unique::default();
        let mut claim = |errors: &mut ConfigErrors, control: Control, key: &str, value: &str| {
            if let Some(first) = used.claim(control, key) {
                let rule = format!("is already used by {first}");
                errors.add(key, format!("{value:?}"), rule);
            }
        };
        let a = &mut self.axes;
        let raw_axes = [&mut a.throttle, &mut a.roll, &mut a.pitch, &mut a.yaw];
        let none_mapped = raw_axes.iter().all(|a| a.is_none());
        for (slot, (axis, raw)) in AXES.iter().zip(raw_axes).enumerate() {
            let Some(raw) = raw else { continue };
            let prefix = format!("axes.{}", axis.name());
            let config = errors.within(&prefix, |errors| raw.validate(errors));
            // Claimed only by a valid axis (`validate` returns `None` after any problem).
            match config.map(|c| c.input) {
                Some(AxisInput::Abs { code, .. }) => {
                    // An axis used as a stick cannot also be a button, in either direction.
                    let (key, name) = (format!("{prefix}.abs"), abs_name(code));
                    for c in [Control::AbsPositive(code), Control::AbsNegative(code)] {
                        claim(&mut errors, c, &key, &name);
                    }
                }
                Some(AxisInput::Keys {
                    negative, positive, ..
                }) => {
                    for (key, code) in [("negative", negative), ("positive", positive)] {
                        let Some(code) = code else { continue };
                        let (key, name) = (format!("{prefix}.{key}"), crate::codes::key_name(code));
                        claim(&mut errors, Control::Key(code), &key, &name);
                    }
                }
                None => {}
            }
            mapping.axes[slot] = config;
        }
        if none_mapped {
            let rule = "must map at least one of throttle, roll, pitch, yaw ([input.axes.NAME])";
            errors.add("axes", "(none)", rule);
        }
        let b = &self.buttons;
        let (control, previous) = (&b.request_control, &b.previous_vehicle);
        use InputAction as A;
        let mode = |m| Some(A::Mode(m));
        let buttons = [
            ("deadman", &b.deadman, None),
            ("mode_manual", &b.mode_manual, mode(Mode::Manual)),
            ("mode_assisted", &b.mode_assisted, mode(Mode::Assisted)),
            ("mode_auto", &b.mode_auto, mode(Mode::Auto)),
            ("request_control", control, Some(A::RequestControl)),
            ("accept", &b.accept, Some(A::Accept)),
            ("refuse", &b.refuse, Some(A::Refuse)),
            ("finish", &b.finish, Some(A::Finish)),
            ("release", &b.release, Some(A::Release)),
            ("next_vehicle", &b.next_vehicle, Some(A::NextVehicle)),
            ("previous_vehicle", previous, Some(A::PreviousVehicle)),
        ];
        for (name, value, action) in buttons {
            let Some(value) = value else { continue };
            let key = format!("buttons.{name}");
            let Some(control) = Control::parse(value) else {
                let rule = "must name a key or button (\"BTN_SOUTH\", \"KEY_SPACE\") or an axis \
                            direction (\"ABS_HAT0Y-\", \"ABS_Z+\")";
                errors.add(key, format!("{value:?}"), rule);
                continue;
            };
            claim(&mut errors, control, &key, value);
            match action {
                None => mapping.deadman = Some(control),
                Some(a) => mapping.actions.push((control, a)),
            }
        }
        errors.into_result(InputConfig {
            kind,
            source,
            mapping,
        })
    }

    fn validate_source(&mut self, kind: SourceKind, errors: &mut ConfigErrors) -> SourceConfig {
        let path =
            |p: &Option<PathBuf>| p.as_ref().map(|p| format!("{:?}", p.display().to_string()));
        let name = self.name.as_ref().map(|n| format!("{n:?}"));
        let only_ros2 = "only applies to source = \"ros2\"";
        if kind == SourceKind::Ros2 {
            return self.validate_ros2(errors);
        }
        errors.not_for(
            "topic",
            self.topic.as_ref().map(|t| format!("{t:?}")),
            only_ros2,
        );
        errors.not_for("domain_id", self.domain_id, only_ros2);
        errors.not_for("message", self.message.map(|m| format!("{m:?}")), only_ros2);
        errors.not_for("max_linear", self.max_linear, only_ros2);
        errors.not_for("max_angular", self.max_angular, only_ros2);
        let shown = self.interfaces.as_ref().map(|i| format!("{i:?}"));
        errors.not_for("interfaces", shown, only_ros2);
        if kind == SourceKind::Replay {
            let only_devices = "only applies to source = \"joystick\" or \"keyboard\"";
            errors.not_for("device", path(&self.device), only_devices);
            errors.not_for("name", name, only_devices);
            errors.not_for("grab", self.grab, only_devices);
            errors.not_for("reopen_interval_ms", self.reopen_interval_ms, only_devices);
            let file = self.file.clone().unwrap_or_else(|| {
                let rule = "must name the recording to play for source = \"replay\"";
                errors.absent("file", rule);
                PathBuf::new()
            });
            return SourceConfig::Replay { file };
        }
        let only_replay = "only applies to source = \"replay\"";
        errors.not_for("file", path(&self.file), only_replay);
        let selector = match (&self.device, &self.name) {
            (Some(d), Some(n)) => {
                let rule = "give either device or name, not both";
                errors.add("name", format!("{n:?}"), rule);
                DeviceSelector::Path(d.clone())
            }
            (Some(d), None) => {
                if d.as_os_str().is_empty() {
                    errors.add("device", "\"\"", "must be a path");
                }
                DeviceSelector::Path(d.clone())
            }
            (None, Some(n)) => {
                if n.trim().is_empty() {
                    errors.add("name", format!("{n:?}"), "must be a non-empty pattern");
                }
                DeviceSelector::Name(n.clone())
            }
            (None, None) if kind == SourceKind::Keyboard => DeviceSelector::AnyKeyboard,
            (None, None) => DeviceSelector::AnyJoystick,
        };
        let (key, range) = ("reopen_interval_ms", REOPEN_INTERVAL_RANGE_MS);
        let reopen = self
            .reopen_interval_ms
            .get_or_insert(DEFAULT_REOPEN_INTERVAL_MS);
        let reopen = errors.int(key, *reopen, range, " ms").unwrap_or_default();
        let grab = *self.grab.get_or_insert(false);
        SourceConfig::Evdev {
            selector,
            grab,
            reopen_interval: Duration::from_millis(reopen),
        }
    }
}

impl AxisSettings {
    /// Validates one axis; keys in errors are relative to the axis table.
    fn validate(&mut self, errors: &mut ConfigErrors) -> Option<AxisConfig> {
        let before = errors.0.len();
        let expo = *self.expo.get_or_insert(0.0);
        let expo = errors.float("expo", expo, EXPO_RANGE, "must be 0..=1");
        let scale_pct = *self.scale_pct.get_or_insert(100.0);
        if !(scale_pct > 0.0 && scale_pct <= 100.0) {
            let rule = "must be greater than 0 and at most 100";
            errors.add("scale_pct", scale_pct, rule);
        }
        let has_keys = self.negative.is_some() || self.positive.is_some();
        let input = match (self.abs.clone(), has_keys) {
            (Some(name), true) => {
                let rule = "give either abs or negative/positive keys, not both";
                errors.add("abs", format!("{name:?}"), rule);
                None
            }
            (None, false) => {
                let rule = "must name an absolute axis (\"ABS_X\"), or give negative/positive keys";
                errors.add("abs", ABSENT, rule);
                None
            }
            (Some(name), false) => self.validate_abs(&name, errors),
            (None, true) => self.validate_keys(errors),
        };
        let input = input?;
        (errors.0.len() == before).then_some(AxisConfig {
            input,
            reverse: *self.reverse.get_or_insert(false),
            expo,
            scale: scale_pct / 100.0,
            rest: *self.rest.get_or_insert_default(),
        })
    }

    fn validate_abs(&self, name: &str, errors: &mut ConfigErrors) -> Option<AxisInput> {
        let not_for_abs = "only applies to key axes (negative/positive)";
        errors.not_for("ramp_up_ms", self.ramp_up_ms, not_for_abs);
        errors.not_for("spring_back_ms", self.spring_back_ms, not_for_abs);
        let code = parse_abs(name);
        if code.is_none() {
            let rule = "must name an absolute axis, e.g. \"ABS_X\", \"ABS_RY\", \"ABS_HAT0X\"";
            errors.add("abs", format!("{name:?}"), rule);
        }
        let deadband = |d| errors.float("deadband_pct", d, DEADBAND_RANGE_PCT, "must be 0..=50");
        let deadzone = self.deadband_pct.map(deadband).map(|d| d / 100.0);
        let mut raw = |key: &str, v: Option<Int>| {
            errors.opt_int::<i32>(key, v, Int::from(i32::MIN)..=Int::from(i32::MAX), "")
        };
        let (min, centre) = (raw("min", self.min), raw("centre", self.centre));
        let max = raw("max", self.max);
        if let (Some(min), Some(max)) = (self.min, self.max)
            && min >= max
        {
            errors.add("max", max, format!("must be greater than min ({min})"));
        }
        if let Some(centre) = self.centre {
            if let Some(min) = self.min.filter(|m| centre <= *m) {
                let rule = format!("must be greater than min ({min})");
                errors.add("centre", centre, rule);
            }
            if let Some(max) = self.max.filter(|m| centre >= *m) {
                errors.add("centre", centre, format!("must be less than max ({max})"));
            }
        }
        Some(AxisInput::Abs {
            code: code?,
            min,
            centre,
            max,
            deadzone,
        })
    }

    fn validate_keys(&mut self, errors: &mut ConfigErrors) -> Option<AxisInput> {
        let not_for_keys = "only applies to abs axes";
        errors.not_for("deadband_pct", self.deadband_pct, not_for_keys);
        errors.not_for("min", self.min, not_for_keys);
        errors.not_for("centre", self.centre, not_for_keys);
        errors.not_for("max", self.max, not_for_keys);
        let mut key = |field: &str, value: &Option<String>| -> Option<Option<u16>> {
            let Some(name) = value else { return Some(None) };
            let code = parse_key(name);
            if code.is_none() {
                let rule = "must name a key or button, e.g. \"KEY_W\", \"BTN_TL\"";
                errors.add(field, format!("{name:?}"), rule);
            }
            code.map(Some)
        };
        let negative = key("negative", &self.negative);
        let positive = key("positive", &self.positive);
        if let (Some(Some(n)), Some(Some(p))) = (negative, positive)
            && n == p
        {
            let shown = format!("{:?}", self.positive.as_deref().unwrap_or_default());
            errors.add("positive", shown, "must differ from negative");
        }
        let mut ms = |field: &str, value: &mut Option<Int>, default: Int| {
            let v = *value.get_or_insert(default);
            let ms = errors.int(field, v, 0..=MAX_RAMP_MS, " ms");
            Duration::from_millis(ms.unwrap_or_default())
        };
        let ramp_up = ms("ramp_up_ms", &mut self.ramp_up_ms, DEFAULT_RAMP_UP_MS);
        let back = (&mut self.spring_back_ms, DEFAULT_SPRING_BACK_MS);
        let spring_back = ms("spring_back_ms", back.0, back.1);
        Some(AxisInput::Keys {
            negative: negative?,
            positive: positive?,
            ramp_up,
            spring_back,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> InputSettings {
        toml::from_str(text).expect("test TOML parses")
    }

    fn errors_of(text: &str) -> Vec<String> {
        match parse(text).validate() {
            Ok(_) => Vec::new(),
            Err(rove_core::Error::Config(errors)) => {
                errors.0.iter().map(ToString::to_string).collect()
            }
            Err(e) => vec![e.to_string()],
        }
    }

    #[test]
    fn a_ros_2_source_reads_joy_or_a_twist_and_loses_a_silent_node() {
        let c = parse("source = \"ros2\"\n[axes.throttle]\nabs = \"ABS_Y\"\n")
            .validate()
            .expect("valid");
        assert_eq!(
            &c.source,
            &SourceConfig::Ros2 {
                topic: "/joy".into(),
                message: Ros2Message::Joy,
                max_linear: 0.5,
                max_angular: 1.0,
                domain_id: 0,
                interfaces: vec![std::net::Ipv4Addr::LOCALHOST],
            }
        );
        // The joy node repeats at 20 Hz: silence is detected unless said otherwise.
        assert_eq!(c.mapping.silence_timeout, Some(Duration::from_millis(500)));
        let twist = "source = \"ros2\"\nmessage = \"Twist\"\nmax_linear = 0.2\n\
                     [axes.throttle]\nabs = \"ABS_X\"\n";
        let c = parse(twist).validate().expect("valid");
        assert!(
            matches!(&c.source, SourceConfig::Ros2 { topic, max_linear, .. }
                if topic == "/cmd_vel" && *max_linear == 0.2),
            "{c:?}"
        );
        let errors = errors_of(
            "source = \"ros2\"\ntopic = \"joy\"\ndevice = \"/dev/input/js0\"\ndomain_id = 300\n",
        );
        assert!(
            errors.iter().any(|e| e.starts_with("topic = \"joy\"")),
            "{errors:?}"
        );
        assert!(
            errors.iter().any(|e| e.starts_with("device =")),
            "{errors:?}"
        );
        assert!(
            errors.iter().any(|e| e.starts_with("domain_id = 300")),
            "{errors:?}"
        );
        // The ROS 2 keys do not apply to a joystick.
        let errors = errors_of("source = \"joystick\"\ntopic = \"/joy\"\n");
        assert!(
            errors.iter().any(|e| e.starts_with("topic =")),
            "{errors:?}"
        );
    }

    #[test]
    fn minimal_joystick_takes_defaults() {
        let c = parse(
            r#"
            source = "joystick"
            [axes.roll]
            abs = "ABS_X"
            "#,
        )
        .validate()
        .expect("valid");
        assert_eq!(c.kind, SourceKind::Joystick);
        assert_eq!(
            &c.source,
            &SourceConfig::Evdev {
                selector: DeviceSelector::AnyJoystick,
                grab: false,
                reopen_interval: Duration::from_millis(DEFAULT_REOPEN_INTERVAL_MS as u64),
            }
        );
        let roll = c.mapping.axes[1].expect("roll mapped");
        assert_eq!(
            roll.input,
            AxisInput::Abs {
                code: 0,
                min: None,
                centre: None,
                max: None,
                deadzone: None
            }
        );
        assert_eq!((roll.reverse, roll.expo, roll.scale), (false, 0.0, 1.0));
        assert_eq!(roll.rest, Rest::Centre);
        assert_eq!(c.mapping.silence_timeout, None);
        assert_eq!(c.mapping.deadman, None);
    }

    #[test]
    fn keyboard_axes_take_ramp_defaults() {
        let c = parse(
            r#"
            source = "keyboard"
            [axes.throttle]
            negative = "KEY_S"
            positive = "KEY_W"
            [buttons]
            deadman = "KEY_SPACE"
            release = "KEY_ESC"
            "#,
        )
        .validate()
        .expect("valid");
        assert!(matches!(
            &c.source,
            SourceConfig::Evdev {
                selector: DeviceSelector::AnyKeyboard,
                ..
            }
        ));
        assert_eq!(
            c.mapping.axes[0].map(|a| a.input),
            Some(AxisInput::Keys {
                negative: Some(31),
                positive: Some(17),
                ramp_up: Duration::from_millis(DEFAULT_RAMP_UP_MS as u64),
                spring_back: Duration::from_millis(DEFAULT_SPRING_BACK_MS as u64),
            })
        );
        assert_eq!(c.mapping.deadman, Some(Control::Key(57)));
        assert_eq!(
            c.mapping.actions,
            vec![(Control::Key(1), InputAction::Release)]
        );
    }

    #[test]
    fn rejects_unknown_keys() {
        let err = toml::from_str::<InputSettings>("source = \"joystick\"\ndeadzone = 3\n")
            .expect_err("unknown key");
        assert!(err.to_string().contains("deadzone"), "{err}");
        let err = toml::from_str::<InputSettings>("[axes.throttle]\nabs = \"ABS_Y\"\ndz = 1\n")
            .expect_err("unknown key");
        assert!(err.to_string().contains("dz"), "{err}");
    }

    #[test]
    fn errors_name_every_bad_key_relative_to_input() {
        let got = errors_of(
            r#"
            source = "joystick"
            device = "/dev/input/event3"
            name = "Xbox*"
            file = "x.txt"
            reopen_interval_ms = 1
            silence_timeout_ms = 5
            [axes.throttle]
            abs = "ABS_Q"
            deadzone_pct = 60.0
            expo = 1.5
            scale_pct = 0.0
            ramp_up_ms = 10
            [axes.roll]
            abs = "ABS_X"
            min = 10
            max = 5
            centre = 20
            [axes.yaw]
            negative = "KEY_Q"
            positive = "KEY_NOPE"
            deadzone_pct = 5.0
            [axes.pitch]
            [buttons]
            deadman = "BTN_TL"
            release = "BTN_TL"
            accept = "ABS_HAT0X+"
            finish = "BTN_WHAT"
            refuse = "KEY_Q"
            "#,
        );
        let expected = [
            "file = \"x.txt\": only applies to source = \"replay\"",
            "name = \"Xbox*\": give either device or name, not both",
            "reopen_interval_ms = 1: must be 10..=60000 ms",
            "silence_timeout_ms = 5: must be 50..=600000 ms (leave it out to turn silence detection off)",
            "axes.throttle.expo = 1.5: must be 0..=1",
            "axes.throttle.scale_pct = 0: must be greater than 0 and at most 100",
            "axes.throttle.ramp_up_ms = 10: only applies to key axes (negative/positive)",
            "axes.throttle.abs = \"ABS_Q\": must name an absolute axis, e.g. \"ABS_X\", \"ABS_RY\", \"ABS_HAT0X\"",
            "axes.throttle.deadband_pct = 60: must be 0..=50",
            "axes.roll.max = 5: must be greater than min (10)",
            "axes.roll.centre = 20: must be less than max (5)",
            "axes.pitch.abs = (absent): must name an absolute axis (\"ABS_X\"), or give negative/positive keys",
            "axes.yaw.deadband_pct = 5: only applies to abs axes",
            "axes.yaw.positive = \"KEY_NOPE\": must name a key or button, e.g. \"KEY_W\", \"BTN_TL\"",
            "buttons.release = \"BTN_TL\": is already used by buttons.deadman",
            "buttons.finish = \"BTN_WHAT\": must name a key or button (\"BTN_SOUTH\", \"KEY_SPACE\") or an axis direction (\"ABS_HAT0Y-\", \"ABS_Z+\")",
        ];
        for e in expected {
            assert!(got.iter().any(|g| g == e), "missing {e:?} in:\n{got:#?}");
        }
        // The valid roll mapping is still rejected for its bad calibration, and the yaw axis's
        // valid KEY_Q was claimed: a button on it is an error too.
        assert!(
            got.iter().all(|g| !g.starts_with("buttons.refuse")),
            "yaw was invalid, so KEY_Q was not claimed: {got:#?}"
        );
        assert_eq!(got.len(), expected.len(), "{got:#?}");
    }

    #[test]
    fn older_spellings_are_accepted_and_wide_integers_name_their_key() {
        let c = parse("source = \"joystick\"\n[axes.roll]\nabs = \"ABS_X\"\ninvert = true\ndeadzone_pct = 5.0")
            .validate()
            .expect("aliases");
        let roll = c.mapping.axes[1].expect("roll mapped");
        assert!(roll.reverse);
        assert!(matches!(roll.input, AxisInput::Abs { deadzone: Some(d), .. } if d == 0.05));
        let got = errors_of(
            "source = \"joystick\"\nreopen_interval_ms = -1\n[axes.roll]\nabs = \"ABS_X\"\nmin = 3000000000",
        );
        assert_eq!(
            got,
            [
                "reopen_interval_ms = -1: must be 10..=60000 ms",
                "axes.roll.min = 3000000000: must be -2147483648..=2147483647",
            ]
        );
    }

    #[test]
    fn replay_requires_file_and_rejects_device_keys() {
        let got = errors_of(
            r#"
            source = "replay"
            device = "/dev/input/event0"
            grab = true
            [axes.roll]
            abs = "ABS_X"
            "#,
        );
        assert_eq!(
            got,
            [
                "device = \"/dev/input/event0\": only applies to source = \"joystick\" or \"keyboard\"",
                "grab = true: only applies to source = \"joystick\" or \"keyboard\"",
                "file = (absent): must name the recording to play for source = \"replay\"",
            ]
        );
    }

    #[test]
    fn missing_source_and_axes_are_errors() {
        assert_eq!(
            errors_of(""),
            [
                "source = (absent): must be one of \"joystick\", \"keyboard\", \"replay\", \"ros2\"",
                "axes = (none): must map at least one of throttle, roll, pitch, yaw ([input.axes.NAME])",
            ]
        );
    }

    #[test]
    fn keys_shared_between_an_axis_and_a_button_are_errors() {
        let got = errors_of(
            r#"
            source = "keyboard"
            [axes.yaw]
            negative = "KEY_A"
            positive = "KEY_D"
            [axes.roll]
            negative = "KEY_A"
            [axes.throttle]
            abs = "ABS_Z"
            [buttons]
            release = "KEY_D"
            deadman = "ABS_Z+"
            "#,
        );
        assert_eq!(
            got,
            [
                "axes.yaw.negative = \"KEY_A\": is already used by axes.roll.negative",
                "buttons.deadman = \"ABS_Z+\": is already used by axes.throttle.abs",
                "buttons.release = \"KEY_D\": is already used by axes.yaw.positive",
            ]
        );
    }

    #[test]
    fn validate_as_accepts_a_consumed_tag_and_rejects_a_contradiction() {
        let mut s = parse("file = \"r.txt\"\n[axes.roll]\nabs = \"ABS_X\"\n");
        let c = s.validate_as(SourceKind::Replay).expect("valid replay");
        assert_eq!(
            &c.source,
            &SourceConfig::Replay {
                file: "r.txt".into()
            }
        );
        let mut contradicting = InputSettings {
            source: Some(SourceKind::Joystick),
            ..s
        };
        assert!(contradicting.validate_as(SourceKind::Replay).is_err());
    }

    #[test]
    fn relative_paths_resolve_against_the_config_dir() {
        let mut c =
            parse("source = \"replay\"\nfile = \"rec.txt\"\n[axes.roll]\nabs = \"ABS_X\"\n")
                .validate()
                .expect("valid");
        c.resolve_relative_to(Path::new("/etc/rove"));
        assert_eq!(
            &c.source,
            &SourceConfig::Replay {
                file: "/etc/rove/rec.txt".into()
            }
        );
        let c = c.with_device(DeviceSelector::Path("/dev/input/event7".into()));
        assert_eq!(c.kind, SourceKind::Joystick);
        assert!(matches!(&c.source, SourceConfig::Evdev { .. }));
    }
}
