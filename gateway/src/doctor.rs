//! `rove doctor`: what this computer offers and what a config needs, one line each: `ok`,
//! `missing` or `wrong`, with the fix.
//!
//! It reads only files: sysfs (PWM chips, network interfaces, input device names), `/dev`
//! (GPIO chips, serial ports, input devices, with their owner groups), the device tree's model,
//! `/etc/group` (the service user's groups) and `/proc/net/fib_trie` (the local IPv4
//! addresses). All of them sit under one [`Roots`] so the tests run it on a fake tree.

use crate::config::{AnyConfig, InputChoice, OutputConfig};
use rove_inputs::SourceConfig;
use rove_inputs::config::DeviceSelector;
use rove_pwm::{BackendConfig, ChannelAddress, PwmVehicleConfig};
use std::collections::BTreeSet;
use std::fmt;
use std::net::Ipv4Addr;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

/// Where the system's files are: `/`, or a fake tree in tests.
#[derive(Debug, Clone)]
pub struct Roots(pub PathBuf);

impl Roots {
    /// `path` (absolute, as on the system) under the root.
    fn at(&self, path: impl AsRef<Path>) -> PathBuf {
        let path = path.as_ref();
        self.0.join(path.strip_prefix("/").unwrap_or(path))
    }

    /// The entries of directory `dir` whose names start with `prefix`, sorted.
    fn entries(&self, dir: &str, prefix: &str) -> Vec<String> {
        let mut names: Vec<String> = std::fs::read_dir(self.at(dir))
            .into_iter()
            .flatten()
            .filter_map(|e| e.ok()?.file_name().into_string().ok())
            .filter(|n| n.starts_with(prefix))
            .collect();
        names.sort();
        names
    }

    fn read(&self, path: impl AsRef<Path>) -> Option<String> {
        let text = std::fs::read_to_string(self.at(path)).ok()?;
        Some(
            text.trim_matches(|c: char| c.is_whitespace() || c == '\0')
                .to_string(),
        )
    }
}

/// How a check came out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Status {
    /// Present and usable.
    Ok,
    /// Not there.
    Missing,
    /// There, but not usable as it is (permissions, state).
    Wrong,
}

/// One line of the report.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Finding {
    /// The outcome.
    pub status: Status,
    /// The area and what was found.
    pub what: String,
    /// What to do about it, for `missing` and `wrong`.
    pub fix: Option<String>,
}

impl fmt::Display for Finding {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let status = match self.status {
            Status::Ok => "ok",
            Status::Missing => "missing",
            Status::Wrong => "wrong",
        };
        write!(f, "{status:<8} {}", self.what)?;
        match &self.fix {
            Some(fix) => write!(f, " — {fix}"),
            None => Ok(()),
        }
    }
}

/// `finding` for a device the config does not need: a problem with it is told, not counted.
fn unneeded(finding: Finding) -> Finding {
    match (finding.status, &finding.fix) {
        (Status::Wrong, Some(fix)) => ok(format!(
            "{} (not needed by the config; {fix})",
            finding.what
        )),
        _ => finding,
    }
}

fn ok(what: String) -> Finding {
    Finding {
        status: Status::Ok,
        what,
        fix: None,
    }
}

fn bad(status: Status, what: String, fix: impl Into<String>) -> Finding {
    Finding {
        status,
        what,
        fix: Some(fix.into()),
    }
}

/// The service user and its groups, from `/etc/group`.
struct User<'a> {
    name: &'a str,
    groups: BTreeSet<String>,
    /// gid → group name, for device files.
    names: Vec<(u32, String)>,
}

impl User<'_> {
    fn group_of(&self, gid: u32) -> String {
        (self.names.iter())
            .find(|(g, _)| *g == gid)
            .map_or_else(|| gid.to_string(), |(_, n)| n.clone())
    }

    /// Whether the user can read and write the device file at `path` (system path shown),
    /// through the file's group or its mode for others.
    fn access(&self, area: &str, shown: &str, path: &Path) -> Finding {
        let Ok(meta) = std::fs::metadata(path) else {
            return bad(Status::Missing, format!("{area}: {shown} not present"), "");
        };
        let group = self.group_of(meta.gid());
        let mode = meta.mode();
        let by_group = mode & 0o060 == 0o060 && self.groups.contains(&group);
        let by_others = mode & 0o006 == 0o006;
        let what = format!("{area}: {shown} (group {group}, mode {:o})", mode & 0o777);
        match by_group || by_others {
            true => ok(what),
            false => bad(
                Status::Wrong,
                what,
                format!("usermod -aG {group} {}, then restart the unit", self.name),
            ),
        }
    }
}

/// Every check for `user` on the computer under `roots`, and for `config` if given.
pub fn check(roots: &Roots, user: &str, config: Option<&AnyConfig>) -> Vec<Finding> {
    let mut found = Vec::new();
    let user = read_user(roots, user, &mut found);
    found.extend(model_and_gpio(roots, &user, config));
    found.extend(pwm(roots, config));
    found.extend(serial(roots, &user, config));
    found.extend(can(roots, config));
    found.extend(inputs(roots, &user, config));
    found.extend(network(roots, config));
    found
}

fn read_user<'a>(roots: &Roots, name: &'a str, found: &mut Vec<Finding>) -> User<'a> {
    let text = roots.read("/etc/group").unwrap_or_default();
    let mut user = User {
        name,
        groups: BTreeSet::new(),
        names: Vec::new(),
    };
    for line in text.lines() {
        let fields: Vec<&str> = line.split(':').collect();
        let [group, _, gid, members] = fields[..] else {
            continue;
        };
        if let Ok(gid) = gid.parse() {
            user.names.push((gid, group.to_string()));
        }
        if group == name || members.split(',').any(|m| m.trim() == name) {
            user.groups.insert(group.to_string());
        }
    }
    found.push(match user.groups.is_empty() {
        true => bad(
            Status::Missing,
            format!("user: {name} has no groups in /etc/group"),
            "install the rove package (its postinst creates the user and its device groups)",
        ),
        false => ok(format!(
            "user: {name} in {}",
            Vec::from_iter(user.groups.iter().cloned()).join(", ")
        )),
    });
    user
}

fn pwm_configs(config: Option<&AnyConfig>) -> Option<&PwmVehicleConfig> {
    match config {
        Some(AnyConfig::Vehicle(v)) => match &v.output {
            OutputConfig::Pwm(c) | OutputConfig::Eyedrive(c) => Some(c),
            OutputConfig::Naza(c) => Some(&c.pwm),
            _ => None,
        },
        _ => None,
    }
}

fn model_and_gpio(roots: &Roots, user: &User, config: Option<&AnyConfig>) -> Vec<Finding> {
    let model = (roots.read("/proc/device-tree/model"))
        .or_else(|| roots.read("/sys/firmware/devicetree/base/model"));
    let rppal = pwm_configs(config).is_some_and(|c| c.backend == BackendConfig::Rppal);
    let mut found = vec![match (&model, rppal) {
        (Some(m), true) if !m.contains("Raspberry Pi") => bad(
            Status::Wrong,
            format!("board: {m}"),
            "backend = \"rppal\" needs a Raspberry Pi; use backend = \"sysfs\"",
        ),
        (Some(m), _) => ok(format!("board: {m}")),
        (None, true) => bad(
            Status::Missing,
            "board: no device-tree model (not a Raspberry Pi)".into(),
            "backend = \"rppal\" needs a Raspberry Pi; use backend = \"sysfs\"",
        ),
        (None, false) => ok("board: no device-tree model (a PC?)".into()),
    }];
    let chips = roots.entries("/dev", "gpiochip");
    for chip in &chips {
        let access = user.access(
            "gpio",
            &format!("/dev/{chip}"),
            &roots.at("/dev").join(chip),
        );
        found.push(if rppal { access } else { unneeded(access) });
    }
    if chips.is_empty() && rppal {
        let what = "gpio: no /dev/gpiochip*".to_string();
        found.push(bad(
            Status::Missing,
            what,
            "rppal needs the GPIO character device",
        ));
    }
    found
}

fn pwm(roots: &Roots, config: Option<&AnyConfig>) -> Vec<Finding> {
    let class = "/sys/class/pwm";
    let mut found: Vec<Finding> = (roots.entries(class, "pwmchip").iter())
        .map(|chip| {
            let npwm = roots.read(format!("{class}/{chip}/npwm"));
            ok(format!(
                "pwm: {chip} with {} channels",
                npwm.as_deref().unwrap_or("?")
            ))
        })
        .collect();
    let Some(c) = pwm_configs(config) else {
        return found;
    };
    let BackendConfig::Sysfs { root } = &c.backend else {
        return found;
    };
    for channel in &c.channels {
        let ChannelAddress::Sysfs { chip, channel: n } = channel.address else {
            continue;
        };
        let dir = roots.at(root).join(format!("pwmchip{chip}"));
        let what = format!(
            "pwm: {:?} on {}/pwmchip{chip}/pwm{n}",
            channel.name,
            root.display()
        );
        let npwm: Option<u32> = std::fs::read_to_string(dir.join("npwm"))
            .ok()
            .and_then(|t| t.trim().parse().ok());
        found.push(match npwm {
            _ if !dir.is_dir() => bad(
                Status::Missing,
                what,
                "no such chip: enable the board's PWM (Pi: dtoverlay=pwm-2chan in \
                 /boot/firmware/config.txt) or fix `chip`",
            ),
            Some(npwm) if n >= npwm => bad(
                Status::Wrong,
                what,
                format!("pwmchip{chip} has {npwm} channels (0..{npwm})"),
            ),
            _ => ok(what),
        });
    }
    found
}

fn serial(roots: &Roots, user: &User, config: Option<&AnyConfig>) -> Vec<Finding> {
    let mut ports: Vec<String> = ["ttyAMA", "ttyS0", "ttyUSB", "ttyACM", "serial"]
        .iter()
        .flat_map(|p| roots.entries("/dev", p))
        .map(|n| format!("/dev/{n}"))
        .collect();
    let mut needed = None;
    if let Some(AnyConfig::Vehicle(v)) = config
        && let OutputConfig::Mavlink(m) = &v.output
        && let rove_mavlink::config::Endpoint::Serial { device, .. } = &m.endpoint
    {
        needed = Some(device.clone());
        if !ports.contains(device) {
            ports.push(device.clone());
        }
    }
    (ports.iter())
        .map(|p| match user.access("serial", p, &roots.at(p)) {
            f if f.status == Status::Missing => Finding {
                fix: Some("check `[output] connection` and the cable".into()),
                ..f
            },
            f if needed.as_ref() == Some(p) => f,
            f => unneeded(f),
        })
        .collect()
}

fn can(roots: &Roots, config: Option<&AnyConfig>) -> Vec<Finding> {
    let net = "/sys/class/net";
    // ARPHRD_CAN.
    let is_can = |i: &String| roots.read(format!("{net}/{i}/type")).as_deref() == Some("280");
    let mut interfaces: Vec<String> = roots.entries(net, "").into_iter().filter(is_can).collect();
    let wanted = match config {
        Some(AnyConfig::Vehicle(v)) => match &v.output {
            OutputConfig::Can(c) => Some(c.interface.clone()),
            _ => None,
        },
        _ => None,
    };
    if let Some(w) = wanted.as_ref().filter(|w| !interfaces.contains(w)) {
        interfaces.push(w.clone());
    }
    (interfaces.iter())
        .map(|i| {
            let state = roots.read(format!("{net}/{i}/operstate"));
            let what = format!("can: {i} ({})", state.as_deref().unwrap_or("absent"));
            let up = matches!(state.as_deref(), Some("up" | "unknown"));
            match state {
                None => bad(
                    Status::Missing,
                    what,
                    "load the CAN driver (Pi: dtoverlay=mcp2515-can0,…)",
                ),
                Some(_) if !up && wanted.as_ref() == Some(i) => bad(
                    Status::Wrong,
                    what,
                    format!("ip link set {i} up type can bitrate 500000 (the bus's rate)"),
                ),
                Some(_) => ok(what),
            }
        })
        .collect()
}

fn inputs(roots: &Roots, user: &User, config: Option<&AnyConfig>) -> Vec<Finding> {
    let evdev = match config {
        Some(AnyConfig::Operator(o)) => match &o.input {
            InputChoice::Device(i) => matches!(i.source, SourceConfig::Evdev { .. }),
            InputChoice::Constant(..) => false,
        },
        _ => false,
    };
    let mut found: Vec<Finding> = (roots.entries("/dev/input", "event").iter())
        .map(|e| {
            let name = roots.read(format!("/sys/class/input/{e}/device/name"));
            let shown = format!("/dev/input/{e} {:?}", name.unwrap_or_default());
            let access = user.access("input", &shown, &roots.at("/dev/input").join(e));
            if evdev { access } else { unneeded(access) }
        })
        .collect();
    if let Some(AnyConfig::Operator(o)) = config
        && let InputChoice::Device(input) = &o.input
        && let SourceConfig::Evdev { selector, .. } = &input.source
    {
        found.push(match selector {
            DeviceSelector::Path(p) if !roots.at(p).exists() => bad(
                Status::Missing,
                format!("input: {} (the config's device)", p.display()),
                "plug the device in, or list them with `rove inputs list`",
            ),
            other => ok(format!("input: the config's device: {other}")),
        });
    }
    found
}

/// The local IPv4 addresses, from the kernel's routing trie (`/proc/net/fib_trie`: an address
/// line followed by `/32 host LOCAL`).
fn local_addresses(roots: &Roots) -> BTreeSet<Ipv4Addr> {
    let text = roots.read("/proc/net/fib_trie").unwrap_or_default();
    let lines: Vec<&str> = text.lines().collect();
    (lines.windows(2))
        .filter(|w| w[1].contains("/32 host LOCAL"))
        .filter_map(|w| {
            w[0].trim()
                .trim_start_matches(['|', '-', '+', ' '])
                .parse()
                .ok()
        })
        .collect()
}

fn network(roots: &Roots, config: Option<&AnyConfig>) -> Vec<Finding> {
    let common = match config {
        Some(AnyConfig::Vehicle(v)) => &v.common,
        Some(AnyConfig::Operator(o)) => &o.common,
        None => return Vec::new(),
    };
    let local = local_addresses(roots);
    (common.interfaces.iter())
        .map(|a| {
            let what = format!("network: {a} (`[network] interfaces`)");
            match a.is_loopback() || local.contains(a) {
                true => ok(what),
                false => bad(
                    Status::Missing,
                    what,
                    "no local interface has this address: bring the link up (`ip addr`) or fix \
                     the config",
                ),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::PermissionsExt;

    /// A fake system root; device files belong to the test's own user (root: gid 0), so the
    /// fake /etc/group names gid 0 as the device group under test.
    fn tree(name: &str) -> Roots {
        let dir = std::env::temp_dir().join(format!("rove-doctor-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("tree");
        Roots(dir)
    }

    fn put(roots: &Roots, path: &str, text: &str, mode: u32) {
        let path = roots.at(path);
        std::fs::create_dir_all(path.parent().expect("parent")).expect("dirs");
        std::fs::write(&path, text).expect("write");
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(mode)).expect("mode");
    }

    fn vehicle(roots: &Roots, output: &str) -> AnyConfig {
        let text = format!(
            "[device]\nid = 100\n[network]\ninterfaces = [\"10.42.0.2\", \"127.0.0.1\"]\n{output}"
        );
        let path = roots.0.join("vehicle.toml");
        std::fs::write(&path, text).expect("config");
        crate::config::load_any(&path).expect("valid config").0
    }

    fn line<'a>(found: &'a [Finding], starts: &str) -> &'a Finding {
        (found.iter())
            .find(|f| f.what.starts_with(starts))
            .unwrap_or_else(|| panic!("no {starts:?} in {found:#?}"))
    }

    #[test]
    fn a_pi_with_pwm_serial_and_groups_is_reported_and_the_configs_needs_checked() {
        let roots = tree("pi");
        put(
            &roots,
            "/etc/group",
            "root:x:0:rove\ndialout:x:20:\nrove:x:999:\n",
            0o644,
        );
        put(
            &roots,
            "/proc/device-tree/model",
            "Raspberry Pi 4 Model B Rev 1.5\0",
            0o444,
        );
        put(&roots, "/sys/class/pwm/pwmchip0/npwm", "2\n", 0o444);
        put(&roots, "/dev/gpiochip0", "", 0o660);
        put(&roots, "/dev/ttyAMA0", "", 0o600);
        put(&roots, "/sys/class/net/can0/type", "280\n", 0o444);
        put(&roots, "/sys/class/net/can0/operstate", "down\n", 0o444);
        put(&roots, "/sys/class/net/eth0/type", "1\n", 0o444);
        put(
            &roots,
            "/proc/net/fib_trie",
            "Main:\n  +-- 10.42.0.0/24 2 0 2\n     |-- 10.42.0.2\n        /32 host LOCAL\n",
            0o444,
        );
        let config = vehicle(
            &roots,
            "[output]\nadapter = \"eyedrive\"\nbackend = \"sysfs\"\n\
             [output.steering]\nchannel = 1\n[output.throttle]\nchannel = 2\n",
        );
        let found = check(&roots, "rove", Some(&config));
        let shown: Vec<String> = found.iter().map(Finding::to_string).collect();
        eprintln!("{}", shown.join("\n"));

        assert_eq!(line(&found, "user: rove").status, Status::Ok);
        assert_eq!(line(&found, "board: Raspberry Pi 4").status, Status::Ok);
        assert_eq!(line(&found, "gpio: /dev/gpiochip0").status, Status::Ok);
        assert_eq!(
            line(&found, "pwm: pwmchip0 with 2 channels").status,
            Status::Ok
        );
        assert_eq!(line(&found, "pwm: \"steering\"").status, Status::Ok);
        // Channel 2 of a two-channel chip.
        let throttle = line(&found, "pwm: \"throttle\"");
        assert_eq!(throttle.status, Status::Wrong);
        assert!(
            throttle.to_string().contains("has 2 channels"),
            "{throttle}"
        );
        // Mode 0600: no access through the group; told, but not needed by this config.
        let serial = line(&found, "serial: /dev/ttyAMA0");
        assert_eq!(serial.status, Status::Ok);
        assert!(
            serial
                .to_string()
                .contains("not needed by the config; usermod -aG root rove")
        );

        assert_eq!(line(&found, "can: can0 (down)").status, Status::Ok);
        assert!(!found.iter().any(|f| f.what.starts_with("can: eth0")));
        assert_eq!(line(&found, "network: 10.42.0.2").status, Status::Ok);
        assert_eq!(line(&found, "network: 127.0.0.1").status, Status::Ok);
    }

    #[test]
    fn what_a_config_needs_and_the_computer_lacks_is_missing_or_wrong_with_the_fix() {
        let roots = tree("bare");
        put(&roots, "/etc/group", "input:x:0:\n", 0o644);
        let config = vehicle(
            &roots,
            "[output]\nadapter = \"eyedrive\"\nbackend = \"rppal\"\n[output.steering]\n\
             pwm_channel = 0\n[output.throttle]\npin = 13\n",
        );
        let found = check(&roots, "rove", Some(&config));
        assert_eq!(line(&found, "user: rove").status, Status::Missing);
        let board = line(&found, "board: no device-tree model");
        assert_eq!(board.status, Status::Missing);
        assert!(board.to_string().contains("backend = \"sysfs\""), "{board}");
        assert_eq!(
            line(&found, "gpio: no /dev/gpiochip").status,
            Status::Missing
        );
        let net = line(&found, "network: 10.42.0.2");
        assert_eq!(net.status, Status::Missing);
        assert!(net.fix.as_deref().is_some_and(|f| f.contains("ip addr")));

        let can = vehicle(
            &roots,
            "[output]\nadapter = \"can\"\ninterface = \"can1\"\n[output.dronecan]\nnode_id = 10\n\
             [[output.dronecan.servos]]\nactuator_id = 1\nsource = \"roll\"\n",
        );
        let found = check(&roots, "rove", Some(&can));
        assert_eq!(line(&found, "can: can1 (absent)").status, Status::Missing);
        put(&roots, "/sys/class/net/can1/type", "280\n", 0o444);
        put(&roots, "/sys/class/net/can1/operstate", "down\n", 0o444);
        let found = check(&roots, "rove", Some(&can));
        let down = line(&found, "can: can1 (down)");
        assert_eq!(down.status, Status::Wrong);
        assert!(down.to_string().contains("ip link set can1 up"), "{down}");

        let serial = vehicle(
            &roots,
            "[output]\nadapter = \"mavlink\"\nconnection = \"serial:/dev/ttyACM0:115200\"\n",
        );
        let found = check(&roots, "rove", Some(&serial));
        assert_eq!(line(&found, "serial: /dev/ttyACM0").status, Status::Missing);
        put(&roots, "/dev/ttyACM0", "", 0o660);
        let found = check(&roots, "rove", Some(&serial));
        let port = line(&found, "serial: /dev/ttyACM0");
        assert_eq!(
            port.status,
            Status::Wrong,
            "needed, and rove is not in its group"
        );
        assert!(
            port.to_string().contains("usermod -aG input rove"),
            "{port}"
        );
        put(&roots, "/etc/group", "dialout:x:0:rove\n", 0o644);
        let found = check(&roots, "rove", Some(&serial));
        assert_eq!(line(&found, "serial: /dev/ttyACM0").status, Status::Ok);
    }

    #[test]
    fn input_devices_are_listed_by_name_with_their_access() {
        let roots = tree("inputs");
        put(&roots, "/etc/group", "input:x:0:rove\n", 0o644);
        put(&roots, "/dev/input/event3", "", 0o660);
        put(
            &roots,
            "/sys/class/input/event3/device/name",
            "Logitech Gamepad F310\n",
            0o444,
        );
        let found = check(&roots, "rove", None);
        let pad = line(&found, "input: /dev/input/event3 \"Logitech Gamepad F310\"");
        assert_eq!(pad.status, Status::Ok);
        assert!(!found.iter().any(|f| f.what.starts_with("network")));
    }
}
