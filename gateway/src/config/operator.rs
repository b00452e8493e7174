//! An operator's file (`rove operator`): `[operator]`, `[input]`, `[handover]`, `[console]` and the
//! validated [`OperatorConfig`].

use super::*;

rove_core::config_types! {
    /// `[operator]`.
    #[derive(Debug, Clone, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct OperatorSection {
        level: Level => "Where the operator is: mobile, stationary or remote.",
        device_class: DeviceClass => "The device: desktop, laptop, tablet or phone.",
        offset: Option<Int> => "Fine offset 0..=9 within the rank (absent: 0).",
        stream_hz: Option<Int> => "Keep-alive stream rate while driving, Hz (absent: 50).",
        #[serde(default)] drive: Vec<DeviceId> => "Vehicles to drive from the start.",
    }

    /// `[input]`: `source` picks constant sticks, an evdev joystick or keyboard, a ROS 2 Joy
    /// topic, or a recorded event stream (the last three are rove-inputs' keys, see `inputs/README.md`).
    #[derive(Debug, Clone, Serialize, Deserialize)]
    #[serde(deny_unknown_fields, tag = "source", rename_all = "lowercase")]
    pub enum InputSection {
        Constant => "Constant stick values." (ConstantInput),
        Joystick => "An evdev joystick or gamepad." (Box<rove_inputs::InputSettings>),
        Keyboard => "An evdev keyboard." (Box<rove_inputs::InputSettings>),
        Replay => "A recorded event stream (tests, demos, benchmarks)."
            (Box<rove_inputs::InputSettings>),
        Ros2 => "A ROS 2 `sensor_msgs/Joy` topic (the standard `joy` node)."
            (Box<rove_inputs::InputSettings>),
    }

    /// A validated `[input]`.
    #[derive(Debug, Clone)]
    pub enum InputChoice {
        Constant => "The same sticks and mode for ever (no `[input]`: centred, MANUAL); driving \
            starts at once." (MovementCommand, Mode),
        Device => "A device or recording; driving waits until it reports live, centred sticks."
            (Box<rove_inputs::InputConfig>),
    }

    /// `[input] source = "constant"`: the same sticks and mode for ever.
    pub table ConstantInput {
        #[serde(default)] throttle: Int => "Throttle axis (absent: 0).",
        #[serde(default)] roll: Int => "Roll axis (absent: 0).",
        #[serde(default)] pitch: Int => "Pitch axis (absent: 0).",
        #[serde(default)] yaw: Int => "Yaw axis (absent: 0).",
        mode: Option<ModeName> => "Mode (absent: manual).",
    }

    /// Mode names in config.
    pub keyword ModeName -> Mode {
        Manual => "MANUAL." = Mode::Manual,
        Assisted => "ASSISTED." = Mode::Assisted,
        Auto => "AUTO." = Mode::Auto,
    }

    /// An operator's file as written.
    #[derive(Debug, Clone, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct RawOperator {
        device: DeviceSection => "`[device]`.",
        #[serde(default)] network: NetworkSection => "`[network]`.",
        #[serde(default)] log: LogSection => "`[log]`.",
        operator: OperatorSection => "`[operator]`.",
        #[serde(default)] hierarchy: HierarchyTable => "`[hierarchy]`: a custom strength table \
            (absent: docs/design.md §3).",
        #[serde(default)] handover: HandoverSettings => "`[handover]`.",
        input: Option<InputSection> => "`[input]` (absent: centred sticks).",
        #[serde(default)] console: ConsoleSection => "`[console]`.",
        security: Option<SecuritySection> => "`[security]`.",
        web: Option<WebSection> => "`[web]`: the browser operator console (docs/web.md).",
    }

    /// `[console]`: the local API for other front ends (docs/api.md).
    pub table ConsoleSection {
        api_socket: Option<std::path::PathBuf> => "Unix socket path of the local API, created with \
            mode 0660 (absent: no API).",
    }

    /// A validated operator configuration.
    #[derive(Debug, Clone)]
    pub struct OperatorConfig {
        common: Common => "Identity and network.",
        level: Level => "Rank in the hierarchy.",
        device_class: DeviceClass => "Device class.",
        strength: Strength => "Ownership strength of the regular writer.",
        stream_period: Duration => "Keep-alive period.",
        drive: Vec<DeviceId> => "Vehicles driven from the start.",
        handover: HandoverConfig => "Active-handover settings.",
        input: InputChoice => "Where stick values and mode come from.",
        api_socket: Option<std::path::PathBuf> => "The local API's socket, if any.",
        web: Option<WebConfig> => "The browser console, if any.",
    }
}

/// Reads and validates an operator config.
///
/// # Errors
/// As [`load_vehicle`].
pub fn load_operator(path: &Path) -> anyhow::Result<OperatorConfig> {
    let text = read(path)?;
    let mut raw: RawOperator = parse(path, &text)?;
    let mut config = raw.validate().map_err(|e| located(path, &text, e))?;
    config.resolve_paths(path);
    Ok(config)
}

impl OperatorConfig {
    /// Makes relative paths in the config (a replay `file`) relative to the file's directory.
    pub fn resolve_paths(&mut self, config_path: &Path) {
        self.common.resolve_paths(config_path);
        let dir = config_path.parent().unwrap_or(Path::new("."));
        if let InputChoice::Device(input) = &mut self.input {
            input.resolve_relative_to(dir);
        }
        if let Some(socket) = &mut self.api_socket {
            *socket = dir.join(&*socket);
        }
        if let Some(web) = &mut self.web {
            if let Some((cert, key)) = &mut web.certificate {
                *cert = dir.join(&*cert);
                *key = dir.join(&*key);
            }
            for device in &mut web.devices {
                device.common.resolve_paths(config_path);
            }
        }
    }
}

impl RawOperator {
    /// Validates, filling defaults into `self`.
    ///
    /// # Errors
    /// [`rove_core::Error::Config`] listing every invalid key.
    pub fn validate(&mut self) -> rove_core::Result<OperatorConfig> {
        let mut errors = ConfigErrors::default();
        let mut common =
            validate_common(&mut self.device, &mut self.network, &self.log, &mut errors);
        common.security = self.security.as_ref().map(|s| s.dir.clone());
        let hierarchy = errors.section("hierarchy", Hierarchy::from_table(&self.hierarchy));
        let hierarchy = hierarchy.unwrap_or(Hierarchy::STANDARD);
        let op = &mut self.operator;
        let (level, class, offset) = (op.level, op.device_class, *op.offset.get_or_insert(0));
        let strength = operator_strength(
            &hierarchy,
            level,
            class,
            offset,
            "operator.offset",
            &mut errors,
        );
        let strength = strength.unwrap_or(Strength(1));
        let stream_hz = *op.stream_hz.get_or_insert(DEFAULT_STREAM_HZ);
        let rule = "; at least 10 keeps a vehicle with the default 100 ms command timeout from \
                    timing out between samples";
        let stream_hz = errors.int::<u32>("operator.stream_hz", stream_hz, 1..=1000, rule);
        let handover = errors.section("handover", self.handover.validate());
        let handover = handover.unwrap_or_default();
        for (i, v) in op.drive.iter().enumerate() {
            if *v == self.device.id {
                let rule = "is this operator's own device id";
                errors.add(format!("operator.drive[{i}]"), v, rule);
            }
        }
        let constant = InputChoice::Constant(MovementCommand::CENTRED, Mode::Manual);
        let mut device = |settings: &mut rove_inputs::InputSettings, kind| {
            let input = errors.section("input", settings.validate_as(kind));
            input.map_or(constant.clone(), |c| InputChoice::Device(Box::new(c)))
        };
        let centred = || InputSection::Constant(ConstantInput::default());
        let input = match self.input.get_or_insert_with(centred) {
            InputSection::Constant(c) => {
                let range = || i16::MIN.into()..=i16::MAX.into();
                let mut stick = |key, v| errors.int(key, v, range(), "").unwrap_or(0);
                let movement = MovementCommand {
                    throttle: stick("input.throttle", c.throttle),
                    roll: stick("input.roll", c.roll),
                    pitch: stick("input.pitch", c.pitch),
                    yaw: stick("input.yaw", c.yaw),
                };
                InputChoice::Constant(movement, (*c.mode.get_or_insert(ModeName::Manual)).into())
            }
            InputSection::Joystick(s) => device(s, rove_inputs::SourceKind::Joystick),
            InputSection::Keyboard(s) => device(s, rove_inputs::SourceKind::Keyboard),
            InputSection::Replay(s) => device(s, rove_inputs::SourceKind::Replay),
            InputSection::Ros2(s) => device(s, rove_inputs::SourceKind::Ros2),
        };
        let mut config = OperatorConfig {
            common,
            level,
            device_class: class,
            strength,
            stream_period: Duration::from_secs_f64(1.0 / f64::from(stream_hz.unwrap_or(1))),
            drive: self.operator.drive.clone(),
            handover,
            input,
            api_socket: self.console.api_socket.clone(),
            web: None,
        };
        if let Some(web) = &mut self.web {
            config.web = errors.within("web", |e| web.validate(&config, &hierarchy, e));
        }
        errors.into_result(config)
    }
}

/// An operator's strength from its level, class and `offset` (written at `key`): the offset
/// is checked against 0..=9, the rest is the hierarchy's.
pub(super) fn operator_strength(
    hierarchy: &Hierarchy,
    level: Level,
    class: DeviceClass,
    offset: Int,
    key: &str,
    errors: &mut ConfigErrors,
) -> Option<Strength> {
    let offset_range = 0..=Int::from(rove_core::hierarchy::MAX_OFFSET);
    (errors.int(key, offset, offset_range, ""))
        .and_then(|o| hierarchy.strength(level, class, o).ok())
}
