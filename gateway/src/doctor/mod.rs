//! `rove doctor`: what this computer offers and what a config needs, one line each: `ok`,
//! `missing` or `wrong`, with the fix.
//!
//! It reads only files: sysfs (PWM chips, network interfaces, input device names), `/dev`
//! (GPIO chips, serial ports, input devices, with their owner groups), the device tree's model,
//! `/etc/group` (the service user's groups) and `/proc/net/fib_trie` (the local IPv4
//! addresses). All of them sit under one [`Roots`] so the tests run it on a fake tree.

use crate::config::{AnyConfig, InputChoice};
use rove_core::adapter::Need;
use rove_inputs::SourceConfig;
use rove_inputs::config::DeviceSelector;
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
    /// Usable now, but not for long (a certificate near its end): told, not counted.
    Warning,
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
            Status::Warning => "warning",
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
    /// through the file's group or its mode for others; if not, how to give it access without
    /// handing it more than the device (see [`PRIVILEGED_GROUPS`]).
    fn access(&self, area: &str, shown: &str, path: &Path) -> Finding {
        let Ok(meta) = std::fs::metadata(path) else {
            return bad(Status::Missing, format!("{area}: {shown} not present"), "");
        };
        let group = self.group_of(meta.gid());
        let mode = meta.mode();
        let by_group = mode & 0o060 == 0o060 && self.groups.contains(&group);
        let by_others = mode & 0o006 == 0o006;
        let what = format!("{area}: {shown} (group {group}, mode {:o})", mode & 0o777);
        if by_group || by_others {
            return ok(what);
        }
        let fix = if PRIVILEGED_GROUPS.contains(&group.as_str()) {
            self.udev_advice(area, &group, path)
        } else if mode & 0o060 != 0o060 {
            let join = match self.groups.contains(&group) {
                true => String::new(),
                false => format!("usermod -aG {group} {}, ", self.name),
            };
            format!(
                "its group {group} cannot read and write it (mode {:o}): a udev rule can set \
                 MODE=\"0660\" (docs/deploy.md, udev rules); then {join}restart the unit",
                mode & 0o777
            )
        } else {
            format!("usermod -aG {group} {}, then restart the unit", self.name)
        };
        bad(Status::Wrong, what, fix)
    }

    /// The advice for a device only a privileged group can reach: never that group; a udev
    /// rule that gives the device to the group made for its kind.
    fn udev_advice(&self, area: &str, group: &str, path: &Path) -> String {
        let kernel = (std::fs::canonicalize(path).ok())
            .and_then(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
            .unwrap_or_default();
        let (subsystem, right) = match area {
            "serial" => ("tty", "dialout"),
            "gpio" => ("gpio", "gpio"),
            _ => ("input", "input"),
        };
        let join = match self.groups.contains(right) {
            true => String::new(),
            false => format!("usermod -aG {right} {}, ", self.name),
        };
        format!(
            "only {group}'s group can reach it, and {group} gives far more than a device: never \
             add {} to it. Give the device to {right} with a udev rule, e.g. in \
             /etc/udev/rules.d/90-rove.rules: SUBSYSTEM==\"{subsystem}\", KERNEL==\"{kernel}\", \
             GROUP=\"{right}\", MODE=\"0660\"; then udevadm control --reload && udevadm \
             trigger, {join}then restart the unit",
            self.name
        )
    }
}

/// Groups whose members can do far more than use one device (root's own, the administrators',
/// raw disks and memory, every terminal (`tty`: a Pi's serial console is `root:tty`), the logs,
/// container runtimes that start root processes): `rove
/// doctor` never tells the service user to join one.
const PRIVILEGED_GROUPS: [&str; 14] = [
    "root",
    "sudo",
    "wheel",
    "admin",
    "adm",
    "disk",
    "kmem",
    "shadow",
    "staff",
    "tty",
    "docker",
    "lxd",
    "libvirt",
    "systemd-journal",
];

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
    #[cfg(feature = "security")]
    found.extend(certificate(config));
    found.extend(failsafe_memory(config, crate::dirs::runtime_location()));
    found
}

/// A MAVLink vehicle: where its link keeps what `rove failsafe` needs (the autopilot's ids and
/// address), or that nothing is kept and the failsafe waits for the autopilot.
fn failsafe_memory(
    config: Option<&AnyConfig>,
    runtime: Option<crate::dirs::RuntimeDir>,
) -> Option<Finding> {
    let Some(AnyConfig::Vehicle(v)) = config else {
        return None;
    };
    if !v.output.needs().contains(&Need::Memory) {
        return None;
    }
    let file = format!("vehicle-{}-{}", v.common.id, v.output.adapter());
    Some(match runtime {
        Some(dir) => ok(format!(
            "failsafe memory: {} ({})",
            dir.path.join(file).display(),
            dir.source
        )),
        None => bad(
            Status::Missing,
            "failsafe memory: no runtime directory (no RUNTIME_DIRECTORY or XDG_RUNTIME_DIR, \
             not root)"
                .into(),
            "run the vehicle under systemd (the unit's RuntimeDirectory=) or set XDG_RUNTIME_DIR: \
             without it `rove failsafe` waits up to a second for the autopilot's HEARTBEAT",
        ),
    })
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

/// What the vehicle's output needs of the computer (nothing for other configs).
fn needs(config: Option<&AnyConfig>) -> Vec<Need> {
    match config {
        Some(AnyConfig::Vehicle(v)) => v.output.needs(),
        _ => Vec::new(),
    }
}

fn model_and_gpio(roots: &Roots, user: &User, config: Option<&AnyConfig>) -> Vec<Finding> {
    let model = (roots.read("/proc/device-tree/model"))
        .or_else(|| roots.read("/sys/firmware/devicetree/base/model"));
    let rppal = needs(config).contains(&Need::RaspberryPi);
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
    for need in needs(config) {
        let Need::PwmChannel {
            name,
            root,
            chip,
            channel: n,
        } = need
        else {
            continue;
        };
        let dir = roots.at(&root).join(format!("pwmchip{chip}"));
        let what = format!("pwm: {name:?} on {}/pwmchip{chip}/pwm{n}", root.display());
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
    let needed = needs(config).into_iter().find_map(|n| match n {
        Need::Serial(device) => Some(device),
        _ => None,
    });
    if let Some(device) = needed.as_ref().filter(|d| !ports.contains(d)) {
        ports.push(device.clone());
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
    let wanted = needs(config).into_iter().find_map(|n| match n {
        Need::Can(interface) => Some(interface),
        _ => None,
    });
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
        Some(AnyConfig::Bridge(b)) => &b.common,
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

/// `[security]`: the device's certificate, and how long it is still valid.
#[cfg(feature = "security")]
fn certificate(config: Option<&AnyConfig>) -> Vec<Finding> {
    use crate::certs::{Expiry, WARN_DAYS};
    let common = match config {
        Some(AnyConfig::Vehicle(v)) => &v.common,
        Some(AnyConfig::Operator(o)) => &o.common,
        Some(AnyConfig::Bridge(b)) => &b.common,
        None => return Vec::new(),
    };
    let Some(dir) = &common.security else {
        return Vec::new();
    };
    let path = dir.join("cert.pem");
    let id = common.id;
    let renew = format!(
        "on the fleet's machine: rove keys add --dir FLEET --id {id} --renew, then copy \
         FLEET/{id}/ to {}",
        dir.display()
    );
    let expiry = std::fs::read(&path)
        .map_err(anyhow::Error::from)
        .and_then(|pem| Expiry::of(&pem));
    let what = |state: &str| format!("security: certificate {} {state}", path.display());
    vec![match expiry {
        Err(e) => bad(
            Status::Missing,
            what(&format!("unreadable ({e:#})")),
            format!("on the fleet's machine: rove keys add --dir FLEET --id {id}"),
        ),
        Ok(x) if !x.valid() => bad(Status::Wrong, what(&x.describe()), renew),
        Ok(x) if x.days_left < WARN_DAYS => Finding {
            status: Status::Warning,
            what: what(&x.describe()),
            fix: Some(renew),
        },
        Ok(x) => ok(what(&x.describe())),
    }]
}

#[cfg(test)]
mod tests;
