//! `rove-testkit`: helpers shared by the tests of several crates, never by shipped code (a
//! dev-dependency only).
//!
//! - [`eventually`]: poll a condition until a deadline; the one way tests wait for something
//!   another process or thread does (no fixed sleeps for synchronisation).
//! - [`FakeAutopilot`]: `fake_autopilot.py` (pymavlink, beside this crate's manifest) as a child
//!   process, and its JSON-lines record; [`python`] finds the interpreter that has pymavlink
//!   and [`require_tool`] fails a test at once, naming the fix, when a peer is missing. Used by `rove-mavlink`'s adapter tests
//!   (`adapters/mavlink/tests/autopilot.rs`) and by the end-to-end tests in `tests/`.

use serde_json::Value;
use std::fmt::Display;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// How long [`eventually`] waits. Generous: a loaded 2-core CI machine starting several
/// processes at once.
pub const PATIENCE: Duration = Duration::from_secs(20);

/// How often [`eventually`] polls.
const POLL: Duration = Duration::from_millis(10);

/// Polls `probe` until it returns `Ok`, for at most [`PATIENCE`], and returns that value.
///
/// # Panics
/// When the deadline passes: the message names `what` and the last `Err` (say there what was
/// seen instead, so that a failure explains itself).
pub fn eventually<T, E: Display>(what: &str, probe: impl FnMut() -> Result<T, E>) -> T {
    eventually_within(PATIENCE, what, probe)
}

/// [`eventually`] with a deadline of `patience`.
///
/// # Panics
/// When the deadline passes, as [`eventually`].
pub fn eventually_within<T, E: Display>(
    patience: Duration,
    what: &str,
    mut probe: impl FnMut() -> Result<T, E>,
) -> T {
    let deadline = Instant::now() + patience;
    loop {
        match probe() {
            Ok(value) => return value,
            Err(why) if Instant::now() >= deadline => {
                panic!("{what}: not within {patience:?}; last seen: {why}")
            }
            Err(_) => std::thread::sleep(POLL),
        }
    }
}

/// The Python interpreter for the test peers: `ROVE_TEST_PYTHON` if set, else the project's
/// virtual environment `.venv/bin/python3` (`scripts/test` creates it), else `python3`.
pub fn python() -> PathBuf {
    if let Some(p) = std::env::var_os("ROVE_TEST_PYTHON") {
        return PathBuf::from(p);
    }
    let venv = repo_root().join(".venv/bin/python3");
    if venv.exists() {
        venv
    } else {
        PathBuf::from("python3")
    }
}

/// The repository's root directory.
pub fn repo_root() -> PathBuf {
    let testkit = Path::new(env!("CARGO_MANIFEST_DIR"));
    testkit.parent().unwrap_or(testkit).to_path_buf()
}

/// How to install the test peers, for failure messages.
const INSTALL: &str = "run `scripts/test` (it installs the prerequisites and creates .venv), \
     or `python3 -m venv .venv && .venv/bin/pip install pymavlink==2.4.50 pyserial==3.5 \
     cyclonedds==11.0.1`";

/// Checks, once per test binary, that [`python`] runs and imports pymavlink, pyserial and
/// cyclonedds (the rogue DDS peer).
///
/// # Panics
/// At once, naming the interpreter, what it lacks and the command that installs it (instead
/// of a test waiting for an autopilot that can never start).
pub fn require_python_peers() {
    static CHECKED: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    let checked = CHECKED.get_or_init(|| {
        let python = python();
        let out = Command::new(&python)
            .args(["-c", "import pymavlink, serial, cyclonedds"])
            .stdin(Stdio::null())
            .output()
            .map_err(|e| format!("{} does not run ({e}): {INSTALL}", python.display()))?;
        if out.status.success() {
            Ok(())
        } else {
            Err(format!(
                "{} lacks the test autopilot's packages ({}): {INSTALL}",
                python.display(),
                String::from_utf8_lossy(&out.stderr)
                    .trim()
                    .lines()
                    .last()
                    .unwrap_or("")
            ))
        }
    });
    if let Err(why) = checked {
        panic!("{why}");
    }
}

/// Checks that the program `tool` is on the PATH.
///
/// # Panics
/// At once, naming `tool` and the Debian package (`package`) that provides it.
pub fn require_tool(tool: &str, package: &str) {
    let found = std::env::var_os("PATH")
        .is_some_and(|path| std::env::split_paths(&path).any(|dir| dir.join(tool).is_file()));
    assert!(
        found,
        "{tool} is not installed: run `scripts/test`, or `apt-get install {package}`"
    );
}

/// The rogue DDS peer (Cyclone DDS speaking rove's wire model); its docstring lists the
/// attacks and their options.
pub fn rogue_script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("rogue.py")
}

/// The crafted-packet sender (`rtps_bomb.py`: raw RTPS datagrams built with Python's standard
/// library; its docstring says what it sends).
pub fn rtps_bomb_script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("rtps_bomb.py")
}

/// The sprayer (`rtps_spray.py`: captures a fleet's own RTPS datagrams on `lo` and sends
/// mutated copies back to where each went, standard library only; its docstring gives the
/// capture file's format, the mutations and the JSON it prints).
pub fn rtps_spray_script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("rtps_spray.py")
}

/// The pymavlink autopilot script (ArduPilot or PX4 as a ground station sees it); its
/// docstring lists its options and what it records.
pub fn fake_autopilot_script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fake_autopilot.py")
}

/// `testkit/fake_gcs.py`: the test ground station ([`FakeAutopilot::start_gcs`]).
pub fn fake_gcs_script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fake_gcs.py")
}

/// A running [`fake_autopilot_script`] and its record (JSON lines, one per event, each with
/// a monotonic `t` and a wall-clock `wall_us`). Killed on drop.
///
/// Needs [`python`] with `pymavlink` (`pyserial` for serial links); `scripts/test` installs
/// them, and a test without them fails at once saying so.
#[derive(Debug)]
pub struct FakeAutopilot {
    child: Child,
    record: PathBuf,
    /// The temp directory holding the record, when the autopilot made it itself.
    _dir: Option<tempfile::TempDir>,
}

impl FakeAutopilot {
    /// Starts the autopilot with `args` (e.g. `--connection udpin:127.0.0.1:PORT`) on this
    /// host's network, recording into a temp directory of its own; returns once it is ready.
    ///
    /// # Panics
    /// [`python`] does not run or lacks pymavlink (at once), or the autopilot is not ready
    /// within [`PATIENCE`].
    pub fn start(args: &[&str]) -> FakeAutopilot {
        let dir = tempfile::tempdir().expect("temp dir for the autopilot's record");
        let record = dir.path().join("autopilot.jsonl");
        let script = fake_autopilot_script();
        FakeAutopilot::spawn(Command::new(python()), &script, record, Some(dir), args)
    }

    /// Starts the test ground station (`testkit/fake_gcs.py`, pymavlink; QGroundControl as
    /// rove's routing sees it) with `args`, recording into a temp directory of its own;
    /// returns once it is ready. Its record and waits are an autopilot's.
    ///
    /// # Panics
    /// As [`FakeAutopilot::start`].
    pub fn start_gcs(args: &[&str]) -> FakeAutopilot {
        let dir = tempfile::tempdir().expect("temp dir for the ground station's record");
        let record = dir.path().join("gcs.jsonl");
        let script = fake_gcs_script();
        FakeAutopilot::spawn(Command::new(python()), &script, record, Some(dir), args)
    }

    /// Starts the autopilot with `args` inside network namespace `netns` (`ip netns exec`),
    /// recording to `record`; returns once it is ready.
    ///
    /// # Panics
    /// As [`FakeAutopilot::start`].
    pub fn start_in_netns(netns: &str, record: &Path, args: &[&str]) -> FakeAutopilot {
        FakeAutopilot::netns(&fake_autopilot_script(), netns, record, args)
    }

    /// The test ground station ([`FakeAutopilot::start_gcs`]) inside network namespace
    /// `netns`, recording to `record`.
    ///
    /// # Panics
    /// As [`FakeAutopilot::start`].
    pub fn start_gcs_in_netns(netns: &str, record: &Path, args: &[&str]) -> FakeAutopilot {
        FakeAutopilot::netns(&fake_gcs_script(), netns, record, args)
    }

    fn netns(script: &Path, netns: &str, record: &Path, args: &[&str]) -> FakeAutopilot {
        let mut command = Command::new("ip");
        command.args(["netns", "exec", netns]).arg(python());
        FakeAutopilot::spawn(command, script, record.to_path_buf(), None, args)
    }

    fn spawn(
        mut command: Command,
        script: &Path,
        record: PathBuf,
        dir: Option<tempfile::TempDir>,
        args: &[&str],
    ) -> FakeAutopilot {
        require_python_peers();
        let child = command
            .arg(script)
            .arg("--record")
            .arg(&record)
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("{} does not run ({e}): {INSTALL}", python().display()));
        let autopilot = FakeAutopilot {
            child,
            record,
            _dir: dir,
        };
        autopilot.wait_for("autopilot ready", |e| e["event"] == "ready");
        autopilot
    }

    /// The UDP or TCP port it listens on, when it was started on port 0 (`udpin:…:0`,
    /// `tcpin:…:0`): it reports the port it got in its `ready` event.
    ///
    /// # Panics
    /// The autopilot reported no port (it was not started listening).
    pub fn port(&self) -> u16 {
        let ready = self.wait_for("autopilot ready", |e| e["event"] == "ready");
        ready["port"]
            .as_u64()
            .and_then(|p| u16::try_from(p).ok())
            .expect("a udpin/tcpin autopilot reports its port")
    }

    /// The record file.
    pub fn record(&self) -> &Path {
        &self.record
    }

    /// Everything the autopilot recorded so far, in order (a line still being written is left
    /// out).
    pub fn events(&self) -> Vec<Value> {
        std::fs::read_to_string(&self.record)
            .unwrap_or_default()
            .lines()
            .filter_map(|l| serde_json::from_str(l).ok())
            .collect()
    }

    /// The recorded events named `event`.
    pub fn of(&self, event: &str) -> Vec<Value> {
        self.events()
            .into_iter()
            .filter(|e| e["event"] == event)
            .collect()
    }

    /// Waits until a recorded event matches `pred` and returns the first that does.
    ///
    /// # Panics
    /// None within [`PATIENCE`]: the message shows the last events.
    pub fn wait_for(&self, what: &str, pred: impl Fn(&Value) -> bool) -> Value {
        eventually(&format!("autopilot: {what}"), || {
            let events = self.events();
            match events.iter().find(|e| pred(e)) {
                Some(e) => Ok(e.clone()),
                None => Err(format!(
                    "{} events, the last ones: {:#?}",
                    events.len(),
                    events.iter().rev().take(8).rev().collect::<Vec<_>>()
                )),
            }
        })
    }

    /// Kills the autopilot (a crash, or the end of a link).
    pub fn stop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Drop for FakeAutopilot {
    fn drop(&mut self) {
        self.stop();
    }
}

/// Two linked pseudo-terminals (`socat`), a serial link without hardware: what one end writes,
/// the other reads; either end can be closed and opened again. Killed on drop.
#[derive(Debug)]
pub struct PtyPair {
    child: Child,
    /// One end (the autopilot's, by convention).
    pub a: PathBuf,
    /// The other end (the vehicle's).
    pub b: PathBuf,
    _dir: tempfile::TempDir,
}

impl PtyPair {
    /// Starts `socat` and waits for both ends.
    ///
    /// # Panics
    /// socat is missing (at once, naming the package) or makes no ptys within [`PATIENCE`].
    pub fn start() -> PtyPair {
        require_tool("socat", "socat");
        let dir = tempfile::tempdir().expect("temp dir for the ptys");
        let (a, b) = (dir.path().join("ttyA"), dir.path().join("ttyB"));
        let child = Command::new("socat")
            .args([
                format!("pty,raw,echo=0,link={}", a.display()),
                format!("pty,raw,echo=0,link={}", b.display()),
            ])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("socat runs");
        let pair = PtyPair {
            child,
            a,
            b,
            _dir: dir,
        };
        eventually("socat makes two ptys", || {
            match pair.a.exists() && pair.b.exists() {
                true => Ok(()),
                false => Err("not yet"),
            }
        });
        pair
    }
}

impl Drop for PtyPair {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::cell::Cell;

    #[test]
    fn eventually_returns_the_first_ok() {
        let calls = Cell::new(0);
        let got = eventually("third call", || {
            calls.set(calls.get() + 1);
            if calls.get() == 3 {
                Ok(calls.get())
            } else {
                Err("not yet")
            }
        });
        assert_eq!(got, 3);
    }

    #[test]
    #[should_panic(expected = "never: not within 30ms; last seen: still 7")]
    fn eventually_panics_with_the_last_error_at_the_deadline() {
        eventually_within(Duration::from_millis(30), "never", || {
            Err::<(), _>("still 7")
        });
    }

    #[test]
    fn the_script_is_where_the_launcher_looks() {
        assert!(fake_autopilot_script().is_file());
    }
}
