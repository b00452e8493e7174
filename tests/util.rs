//! What the end-to-end modules share: the `rove` binary, the rig (processes in a network
//! namespace of the test's own), config builders, the fake sysfs PWM class, the fake autopilot
//! and the deadline poller.
//!
//! The process harness itself ([`rove_tools::harness`]) ships in the library because `rove
//! demo` and `rove bench` run on it too; what only tests need lives here, or in `rove-testkit`
//! when another crate's tests need it as well.

use serde_json::Value;
use std::fmt;
use std::ops::{Deref, DerefMut};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicUsize, Ordering};

pub use rove_testkit::{FakeAutopilot, PATIENCE, eventually, repo_root};
pub use rove_tools::harness::{records, wait_for_output, wall_us};

/// The `rove` binary under test: Cargo builds it for this test target, which is declared in
/// `gateway/Cargo.toml`, the package of the binary.
pub const ROVE: &str = env!("CARGO_BIN_EXE_rove");

// ---------------------------------------------------------------------------------------------
// The rig

/// A fresh network namespace (loopback with multicast) and directory, running [`ROVE`]:
/// [`rove_tools::harness::Rig`] plus what only tests ask of it. Children are killed and the
/// namespace deleted on drop; if the test failed, every child's log is printed.
#[derive(Debug)]
pub struct Rig(rove_tools::harness::Rig);

impl Rig {
    /// A rig named after `test`.
    ///
    /// # Panics
    /// The namespace cannot be created (needs root and iproute2).
    pub fn new(test: &str) -> Rig {
        Rig(rove_tools::harness::Rig::new(Path::new(ROVE), test).unwrap_or_else(|e| panic!("{e}")))
    }

    /// Runs a shell command inside the namespace (e.g. to send raw datagrams).
    pub fn sh(&self, script: &str) -> Result<(), String> {
        let out = Command::new("ip")
            .args(["netns", "exec", &self.ns, "bash", "-c", script])
            .output()
            .map_err(|e| format!("ip netns exec: {e}"))?;
        if out.status.success() {
            Ok(())
        } else {
            Err(format!(
                "{script}: {}",
                String::from_utf8_lossy(&out.stderr).trim()
            ))
        }
    }

    /// The log so far of the first process started as `name` (`vehicle-100`, `operator-11`).
    pub fn log_of(&self, name: &str) -> String {
        let proc = self.procs.iter().find(|p| p.name == name).expect("process");
        std::fs::read_to_string(&proc.log).unwrap_or_default()
    }

    /// `rove status --json` in the namespace.
    pub fn status(&self) -> Value {
        let out = Command::new("ip")
            .args(["netns", "exec", &self.ns, ROVE, "status", "--json"])
            .args(["--listen-ms", "1200"])
            .output()
            .expect("run rove status");
        let text = String::from_utf8_lossy(&out.stdout);
        serde_json::from_str(text.trim()).unwrap_or_else(|e| {
            panic!(
                "status output is not JSON ({e}): {text}\n{}",
                String::from_utf8_lossy(&out.stderr)
            )
        })
    }

    /// `rove status --json`'s row of device `id`, once it satisfies `want` (`what` names the
    /// wait if it never does).
    pub fn device_when(&self, what: &str, id: i64, want: impl Fn(&Value) -> bool) -> Value {
        eventually(what, || {
            let status = self.status();
            match Rig::device(&status, id) {
                Some(d) if want(&d) => Ok(d),
                _ => Err(status),
            }
        })
    }

    /// The device row of `id` in a status snapshot.
    pub fn device(status: &Value, id: i64) -> Option<Value> {
        status["devices"]
            .as_array()?
            .iter()
            .find(|d| d["id"] == id)
            .cloned()
    }

    /// The foreign DDS peer (Cyclone DDS, `testkit/rogue.py ARGS`) in the rig's namespace, not
    /// started yet.
    pub fn foreign_peer(&self, args: &[&str]) -> Command {
        rove_testkit::require_python_peers();
        let mut cmd = Command::new("ip");
        cmd.args(["netns", "exec", &self.ns])
            .arg(rove_testkit::python())
            .arg(rove_testkit::rogue_script())
            .args(args);
        cmd
    }

    /// The fake autopilot with `args`, in the rig's namespace, recording to
    /// `DIR/autopilot.jsonl`; returns once it is ready.
    pub fn autopilot(&self, args: &[&str]) -> FakeAutopilot {
        FakeAutopilot::start_in_netns(&self.ns, &self.dir.join("autopilot.jsonl"), args)
    }

    /// The test ground station (`testkit/fake_gcs.py`) in the rig's namespace, recording to
    /// `NAME.jsonl` in the rig's directory.
    pub fn gcs(&self, name: &str, args: &[&str]) -> FakeAutopilot {
        FakeAutopilot::start_gcs_in_netns(&self.ns, &self.dir.join(format!("{name}.jsonl")), args)
    }
}

impl Deref for Rig {
    type Target = rove_tools::harness::Rig;
    fn deref(&self) -> &Self::Target {
        &self.0
    }
}

impl DerefMut for Rig {
    fn deref_mut(&mut self) -> &mut Self::Target {
        &mut self.0
    }
}

/// The one-line JSON summary a foreign peer (`Rig::foreign_peer`) printed, once it is known to
/// have run and matched a rove endpoint.
pub fn foreign_summary(out: std::process::Output, args: &[&str]) -> Value {
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "foreign peer {args:?} failed: {text}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: Value = serde_json::from_str(text.trim()).expect("summary JSON");
    assert_eq!(
        summary["matched"], true,
        "the foreign peer {args:?} never matched: {summary}"
    );
    summary
}

/// A scratch directory of its own for a test that needs no namespace, removed on drop unless
/// the test failed (or `ROVE_KEEP_RIG` is set, as for the rig).
#[derive(Debug)]
pub struct Scratch {
    pub dir: PathBuf,
}

impl Scratch {
    pub fn new(test: &str) -> Scratch {
        static NEXT: AtomicUsize = AtomicUsize::new(0);
        let n = NEXT.fetch_add(1, Ordering::SeqCst);
        let dir = std::env::temp_dir().join(format!("rove-e2e-{}-{n}-{test}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("scratch dir");
        Scratch { dir }
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if !std::thread::panicking() && std::env::var_os("ROVE_KEEP_RIG").is_none() {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Configs

/// A vehicle's config: device `id` (named `v{id}`) with `output_toml` as its `[output]`.
pub fn vehicle_toml(id: i64, output_toml: &str) -> String {
    format!("[device]\nid = {id}\nname = \"v{id}\"\n{output_toml}")
}

/// An Eyedrive rover on the sysfs PWM backend under `root` (a [`fake_sysfs`]): steering on
/// channel 0, throttle on channel 1.
pub fn eyedrive_sysfs(root: &Path) -> String {
    format!(
        "[output]\nadapter = \"eyedrive\"\nbackend = \"sysfs\"\nsysfs_root = \"{}\"\n\
         [output.steering]\nchannel = 0\n[output.throttle]\nchannel = 1\n",
        root.display()
    )
}

/// An operator's config, for tests that write the file themselves (the rig's `operator` starts
/// one with constant sticks). Prints as TOML.
#[derive(Debug, Clone)]
pub struct OperatorToml {
    id: i64,
    name: String,
    level: String,
    class: String,
    drive: Vec<i64>,
    more: String,
}

impl OperatorToml {
    /// Device `id` (named `op{id}`) at `level` as a `class`, driving nothing, with no `[input]`.
    pub fn new(id: i64, level: &str, class: &str) -> OperatorToml {
        OperatorToml {
            id,
            name: format!("op{id}"),
            level: level.to_string(),
            class: class.to_string(),
            drive: Vec::new(),
            more: String::new(),
        }
    }

    pub fn name(mut self, name: &str) -> OperatorToml {
        self.name = name.to_string();
        self
    }

    /// The vehicles it drives.
    pub fn drive(mut self, vehicles: &[i64]) -> OperatorToml {
        self.drive = vehicles.to_vec();
        self
    }

    /// TOML appended after `[operator]` (e.g. an `[input]` section).
    pub fn then(mut self, toml: &str) -> OperatorToml {
        self.more.push_str(toml);
        self
    }
}

impl fmt::Display for OperatorToml {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let drive: Vec<String> = self.drive.iter().map(i64::to_string).collect();
        write!(
            f,
            "[device]\nid = {}\nname = \"{}\"\n[operator]\nlevel = \"{}\"\n\
             device_class = \"{}\"\ndrive = [{}]\n{}",
            self.id,
            self.name,
            self.level,
            self.class,
            drive.join(", "),
            self.more
        )
    }
}

// ---------------------------------------------------------------------------------------------
// A fake sysfs PWM class

/// A fake sysfs PWM class under `dir`: `pwmchip0` with channels 0 and 1 already exported (the
/// kernel creates `pwmM/` on export; rove-pwm's own tests cover the export step). Returns the
/// class root to put in `sysfs_root`.
pub fn fake_sysfs(dir: &Path) -> PathBuf {
    let root = dir.join("sys-class-pwm");
    for ch in 0..2 {
        let pwm = root.join(format!("pwmchip0/pwm{ch}"));
        std::fs::create_dir_all(&pwm).expect("fake sysfs");
        for (attr, value) in [("period", "0"), ("duty_cycle", "0"), ("enable", "0")] {
            std::fs::write(pwm.join(attr), value).expect("fake sysfs attr");
        }
    }
    std::fs::write(root.join("pwmchip0/export"), "").expect("export file");
    root
}

/// Channel `ch`'s duty cycle in a [`fake_sysfs`] tree, as written (ns).
pub fn duty(root: &Path, ch: u32) -> String {
    std::fs::read_to_string(root.join(format!("pwmchip0/pwm{ch}/duty_cycle")))
        .unwrap_or_default()
        .trim()
        .to_string()
}

/// Waits until channel `ch`'s duty cycle reads `want` (ns).
pub fn wait_duty(root: &Path, ch: u32, want: &str) {
    eventually(&format!("pwm{ch}/duty_cycle = {want}"), || {
        let got = duty(root, ch);
        if got == want {
            Ok(())
        } else {
            Err(format!("{got:?}"))
        }
    });
}

// ---------------------------------------------------------------------------------------------
// Binaries built for another architecture

/// A command running `bin`, through qemu-user when `bin` is an ELF for a board's architecture
/// (aarch64: `qemu-aarch64-static`, 32-bit ARM: `qemu-arm-static`), directly otherwise.
pub fn run_any_arch(bin: &Path) -> Command {
    match elf_arch(bin) {
        Some(arch @ ("arm64" | "armhf")) => {
            let qemu = if arch == "arm64" {
                "qemu-aarch64-static"
            } else {
                "qemu-arm-static"
            };
            rove_testkit::require_tool(qemu, "qemu-user-static");
            let mut command = Command::new(qemu);
            // The board's C library: the cross toolchain's (libc6-dev-*-cross), since nothing
            // of the board's architecture is installed (scripts/board-deb).
            let prefix = if arch == "arm64" {
                "/usr/aarch64-linux-gnu"
            } else {
                "/usr/arm-linux-gnueabihf"
            };
            if Path::new(prefix).join("lib").is_dir() {
                command.env("QEMU_LD_PREFIX", prefix);
            }
            command.arg(bin);
            command
        }
        _ => Command::new(bin),
    }
}

/// Debian's name for the architecture of an ELF executable (`amd64`, `arm64`, `armhf`), read
/// from its header's `e_machine`; `None` if it is not an ELF or of another machine.
pub fn elf_arch(bin: &Path) -> Option<&'static str> {
    let mut header = [0u8; 20];
    let mut file = std::fs::File::open(bin).ok()?;
    std::io::Read::read_exact(&mut file, &mut header).ok()?;
    if &header[..4] != b"\x7fELF" {
        return None;
    }
    match u16::from_le_bytes([header[18], header[19]]) {
        62 => Some("amd64"),
        183 => Some("arm64"),
        40 => Some("armhf"),
        _ => None,
    }
}

/// The applies recorded from `since_us` until 15 ms after `first_fresh_us` (the first fresh
/// apply after a stall): a backlog applied at once would come as such a burst, while fresh
/// samples of a 50 Hz stream come 20 ms apart.
pub fn applies_in_burst(record: &Path, since_us: u64, first_fresh_us: u64) -> Vec<u64> {
    (records(record).iter())
        .filter(|o| o.action == "apply" && o.wall_us >= since_us)
        .map(|o| o.wall_us)
        .filter(|t| *t < first_fresh_us + 15_000)
        .collect()
}

// ---------------------------------------------------------------------------------------------
// Common fleets and process limits

/// Vehicle `vehicle` (sim output, recorded; `vehicle_toml` goes before its `[output]`) and laptop
/// 11 driving it (stationary, throttle 1000; `laptop_toml` at the end of its config), started in
/// that order; waits until the laptop drives. Returns the vehicle's record.
pub fn laptop_drives_sim(
    rig: &mut Rig,
    vehicle: i64,
    vehicle_toml: &str,
    laptop_toml: &str,
) -> PathBuf {
    let output = format!("{vehicle_toml}[output]\nadapter = \"sim\"\n");
    let record = rig.vehicle_with_output(vehicle, &output);
    rig.operator(
        11,
        "stationary",
        "laptop",
        &[vehicle],
        1000,
        laptop_toml,
        &[],
    );
    wait_for_output(&record, Some(11), 0).expect("the laptop drives");
    record
}

/// A field of `/proc/PID/status` in KiB (`VmSize`, `VmRSS`, `VmHWM`); `None` once the process
/// is gone.
pub fn status_kib(pid: u32, field: &str) -> Option<u64> {
    let text = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    (text.lines())
        .find_map(|l| l.strip_prefix(field)?.strip_prefix(':'))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
}

/// Limits `pid`'s address space to what it has mapped now plus `headroom_kib` (util-linux's
/// `prlimit`), so that a runaway allocation aborts that process instead of filling the machine.
pub fn limit_address_space(name: &str, pid: u32, headroom_kib: u64) {
    let size = status_kib(pid, "VmSize").unwrap_or_else(|| panic!("{name} is gone"));
    let limit_bytes = (size + headroom_kib) * 1024;
    let limited = Command::new("prlimit")
        .args(["--pid", &pid.to_string(), &format!("--as={limit_bytes}")])
        .status()
        .expect("prlimit (util-linux)");
    assert!(limited.success(), "prlimit --as on the {name}");
}

/// `rove keys ARGS`, which must succeed.
pub fn keys(args: &[&str]) {
    let out = Command::new(ROVE)
        .arg("keys")
        .args(args)
        .output()
        .expect("rove keys");
    assert!(
        out.status.success(),
        "rove keys {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}
