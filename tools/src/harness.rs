//! Runs real `rove` processes in a network namespace of their own (loopback with multicast, as
//! `docs/rustdds.md` requires): used by the end-to-end tests in `tests/`, `rove demo`
//! and `rove bench` (what only the tests need lives in `tests/util.rs`). Children are killed and
//! the namespace deleted on drop; when a test panics every child's log is printed. Needs root
//! and iproute2 (`ip netns`).

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

static NEXT: AtomicUsize = AtomicUsize::new(0);

/// Generous: a loaded 2-core CI machine starting several DDS processes at once.
pub const PATIENCE: Duration = Duration::from_secs(15);

/// Runs `args` (program first); its stderr in the error when it fails.
pub(crate) fn run(args: &[&str]) -> Result<(), String> {
    let out = Command::new(args[0])
        .args(&args[1..])
        .output()
        .map_err(|e| format!("{args:?}: {e}"))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "{args:?}: {}",
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

/// A running `rove` process.
#[derive(Debug)]
pub struct Proc {
    /// Its name in the rig (`vehicle-100`, `operator-11`), also its log's.
    pub name: String,
    child: Child,
    /// Its stderr (the log).
    pub log: PathBuf,
}

impl Proc {
    /// The process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Still running?
    pub fn is_running(&mut self) -> bool {
        matches!(self.child.try_wait(), Ok(None))
    }

    /// SIGTERM: a graceful stop.
    pub fn terminate(&mut self) {
        self.signal("-TERM");
    }

    /// Sends `signal` (`kill`'s spelling: `-STOP`, `-CONT`, …); whether it was delivered.
    pub fn signal(&self, signal: &str) -> bool {
        Command::new("kill")
            .args([signal, &self.pid().to_string()])
            .status()
            .is_ok_and(|s| s.success())
    }

    /// SIGTERM, then waits for the exit (at most [`PATIENCE`]). For observers: a killed
    /// participant stays matched by every peer for rustdds's 50 s lease, and what it no longer
    /// acknowledges costs every writer repairs, so later measurements would pay for it.
    pub fn stop(&mut self) {
        self.terminate();
        self.wait_exit(PATIENCE);
    }

    /// SIGKILL: a crash.
    pub fn crash(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// Waits for the process to exit; its exit status.
    pub fn wait_exit(&mut self, patience: Duration) -> Option<std::process::ExitStatus> {
        let deadline = Instant::now() + patience;
        while Instant::now() < deadline {
            if let Ok(Some(status)) = self.child.try_wait() {
                return Some(status);
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        None
    }
}

/// A private network namespace could not be created (not root, or no iproute2): callers that
/// can do without real processes (the demo) fall back to running in-process.
#[derive(Debug, thiserror::Error)]
#[error("cannot create a network namespace (needs root and iproute2): {0}")]
pub struct NoNamespace(pub String);

/// One world: a namespace, a directory, processes.
#[derive(Debug)]
pub struct Rig {
    /// The `rove` binary.
    pub rove: PathBuf,
    /// Namespace name.
    pub ns: String,
    /// Directory for configs, logs and records.
    pub dir: PathBuf,
    /// Started processes, in order.
    pub procs: Vec<Proc>,
    /// Environment variables every `rove` started from now on gets (a test hook's).
    pub env: Vec<(String, String)>,
}

impl Rig {
    /// A fresh namespace and directory named after `test`, running `rove`.
    ///
    /// # Errors
    /// The namespace cannot be created (not root, no iproute2).
    pub fn new(rove: &Path, test: &str) -> Result<Rig, NoNamespace> {
        let n = NEXT.fetch_add(1, Ordering::SeqCst);
        let ns = format!("rove-{}-{n}", std::process::id());
        let dir = std::env::temp_dir().join(format!("rove-it-{}-{n}-{test}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("run")).expect("test dir");
        let rig = Rig {
            rove: rove.to_path_buf(),
            ns: ns.clone(),
            dir,
            procs: Vec::new(),
            env: Vec::new(),
        };
        super::cleanup::alive(&ns);
        // Constructed first, so that a failure half-way still deletes the namespace on drop.
        let setup = [
            vec!["ip", "netns", "add", &ns],
            vec!["ip", "-n", &ns, "link", "set", "lo", "up"],
            vec!["ip", "-n", &ns, "link", "set", "lo", "multicast", "on"],
            vec!["ip", "-n", &ns, "route", "add", "224.0.0.0/4", "dev", "lo"],
        ];
        for cmd in setup {
            run(&cmd).map_err(NoNamespace)?;
        }
        Ok(rig)
    }

    /// Writes `text` to `name` in the rig's directory; returns the path.
    pub fn write(&self, name: &str, text: &str) -> PathBuf {
        let path = self.dir.join(name);
        std::fs::write(&path, text).expect("write config");
        path
    }

    /// The runtime directory every `rove` of the rig gets (`RUNTIME_DIRECTORY`, as systemd's
    /// `RuntimeDirectory=` gives it): `DIR/run`. Rigs never share one, whatever the caller's
    /// `XDG_RUNTIME_DIR`.
    pub fn runtime_dir(&self) -> PathBuf {
        self.dir.join("run")
    }

    /// The state directory every `rove` of the rig gets (`STATE_DIRECTORY`, as systemd's
    /// `StateDirectory=` gives it): `DIR/state`, where vehicles keep their audit logs.
    pub fn state_dir(&self) -> PathBuf {
        self.dir.join("state")
    }

    /// `rove ARGS` in the namespace with the rig's environment, not started yet (for a command
    /// that runs to completion, such as `rove failsafe`).
    pub fn command(&self, args: &[&str]) -> Command {
        self.command_scheduled(None, args)
    }

    /// [`Rig::command`], under SCHED_FIFO at priority `fifo` (`chrt -f`) if given.
    fn command_scheduled(&self, fifo: Option<u8>, args: &[&str]) -> Command {
        let chrt = fifo.map(|p| ["chrt".to_string(), "-f".into(), p.to_string()]);
        let mut command = Command::new("ip");
        command
            .arg("netns")
            .arg("exec")
            .arg(&self.ns)
            // The child gets SIGTERM when the thread that started it ends (util-linux): a bench
            // or test that dies leaves no `rove` behind (see also [`super::cleanup`]). A parent
            // that died before `setpriv` armed the signal (between fork and prctl) sends none:
            // the shell, started after the prctl, checks that its parent is still this process
            // and otherwise runs nothing.
            .args(["setpriv", "--pdeathsig", "TERM"])
            .args(["sh", "-c", r#"test "$PPID" = "$0" && exec "$@""#])
            .arg(std::process::id().to_string())
            .args(chrt.iter().flatten())
            .arg(&self.rove)
            .args(args)
            .env("RUNTIME_DIRECTORY", self.runtime_dir())
            // As systemd's `StateDirectory=`: the vehicles' audit logs.
            .env("STATE_DIRECTORY", self.state_dir())
            .env(
                "RUST_LOG",
                std::env::var("ROVE_RIG_LOG").unwrap_or_else(|_| "info,rustdds=warn".into()),
            )
            .envs(self.env.iter().map(|(k, v)| (k, v)))
            .stdin(Stdio::null());
        command
    }

    /// Starts `rove ARGS` in the namespace, logging to `DIR/N-NAME.log`; returns its index.
    pub fn spawn(&mut self, name: &str, args: &[&str]) -> usize {
        self.spawn_scheduled(name, None, args)
    }

    /// [`Rig::spawn`], under SCHED_FIFO at priority `fifo` (`chrt -f`) if given.
    fn spawn_scheduled(&mut self, name: &str, fifo: Option<u8>, args: &[&str]) -> usize {
        let log = self.dir.join(format!("{}-{name}.log", self.procs.len()));
        let file = std::fs::File::create(&log).expect("log file");
        let child = self
            .command_scheduled(fifo, args)
            .stdout(file.try_clone().expect("log"))
            .stderr(file)
            .spawn()
            .expect("spawn rove");
        self.procs.push(Proc {
            name: name.to_string(),
            child,
            log,
        });
        self.procs.len() - 1
    }

    /// A DDS Security fleet for `ids` in the rig's directory (`rove keys init`, then `add` for
    /// each id); returns its directory. Each device's `[security]` is [`security_toml`].
    ///
    /// # Errors
    /// The keys cannot be made, or this build has no security.
    pub fn fleet(&self, ids: &[i64]) -> anyhow::Result<PathBuf> {
        let dir = self.dir.join("fleet");
        let shown = dir.display().to_string();
        keys(
            &self.rove,
            &["init", "--dir", &shown, "--fleet", "rove demo fleet"],
        )?;
        for id in ids {
            keys(
                &self.rove,
                &["add", "--dir", &shown, "--id", &id.to_string()],
            )?;
        }
        Ok(dir)
    }

    /// Starts vehicle `id` (sim adapter) recording its outputs; returns the record path.
    pub fn vehicle(&mut self, id: i64) -> PathBuf {
        self.vehicle_with_output(id, "[output]\nadapter = \"sim\"\n")
    }

    /// Starts vehicle `id` with `output_toml` as its `[output]` section, recording its outputs;
    /// returns the record path.
    pub fn vehicle_with_output(&mut self, id: i64, output_toml: &str) -> PathBuf {
        self.vehicle_scheduled(id, output_toml, None)
    }

    /// [`Rig::vehicle_with_output`], under SCHED_FIFO at priority `fifo` if given (as the
    /// vehicle unit's real-time option runs it).
    pub fn vehicle_scheduled(&mut self, id: i64, output_toml: &str, fifo: Option<u8>) -> PathBuf {
        let config = self.write(
            &format!("vehicle-{id}.toml"),
            &format!("[device]\nid = {id}\nname = \"v{id}\"\n{output_toml}"),
        );
        let record = self.dir.join(format!("vehicle-{id}.jsonl"));
        let args = [
            "vehicle",
            "-c",
            config.to_str().expect("utf-8 path"),
            "--record",
            record.to_str().expect("utf-8 path"),
        ];
        self.spawn_scheduled(&format!("vehicle-{id}"), fifo, &args);
        record
    }

    /// Starts an operator; `extra_toml` is appended to its file (e.g. `[handover]` lines).
    #[allow(clippy::too_many_arguments)]
    pub fn operator(
        &mut self,
        id: i64,
        level: &str,
        class: &str,
        drive: &[i64],
        throttle: i16,
        extra_toml: &str,
        args: &[&str],
    ) -> usize {
        let drive: Vec<String> = drive.iter().map(i64::to_string).collect();
        let config = self.write(
            &format!("operator-{id}-{}.toml", self.procs.len()),
            &format!(
                "[device]\nid = {id}\nname = \"op{id}\"\n[operator]\nlevel = \"{level}\"\n\
                 device_class = \"{class}\"\ndrive = [{}]\n[input]\nsource = \"constant\"\n\
                 throttle = {throttle}\n{extra_toml}\n",
                drive.join(", ")
            ),
        );
        let mut all = vec!["operator", "-c", config.to_str().expect("utf-8 path")];
        all.extend_from_slice(args);
        self.spawn(&format!("operator-{id}"), &all)
    }
}

impl Drop for Rig {
    fn drop(&mut self) {
        for p in &mut self.procs {
            p.crash();
        }
        if std::thread::panicking() {
            for p in &self.procs {
                let log = std::fs::read_to_string(&p.log).unwrap_or_default();
                eprintln!("===== {} ({}) =====\n{log}", p.name, p.log.display());
            }
        }
        let _ = run(&["ip", "netns", "del", &self.ns]);
        super::cleanup::gone(&self.ns);
        // ROVE_KEEP_RIG=1 keeps configs, logs and records for a look after the fact.
        if !std::thread::panicking() && std::env::var_os("ROVE_KEEP_RIG").is_none() {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}

/// Joins two rigs' namespaces by a veth pair, `near_addr` (with its prefix length, such as
/// `10.77.0.1/24`) on `near`'s end and `far_addr` on `far`'s. With `multicast`, `far`'s
/// multicast is routed over the pair (one DDS network over two hosts); without, each keeps
/// its own (two sites that meet only through what is sent to the other's address). Returns
/// the two interface names (near, far).
///
/// # Errors
/// iproute2 refuses a step.
pub fn veth(
    near: &Rig,
    far: &Rig,
    near_addr: &str,
    far_addr: &str,
    multicast: bool,
) -> anyhow::Result<(String, String)> {
    let tag = NEXT.fetch_add(1, Ordering::SeqCst) % 1000;
    let pid = std::process::id() % 100_000;
    let (a, b) = (format!("rv{pid}n{tag}"), format!("rv{pid}f{tag}"));
    let mut steps: Vec<Vec<&str>> = vec![
        vec![
            "ip", "link", "add", &a, "netns", &near.ns, "type", "veth", "peer", "name", &b,
            "netns", &far.ns,
        ],
        vec!["ip", "-n", &near.ns, "addr", "add", near_addr, "dev", &a],
        vec!["ip", "-n", &far.ns, "addr", "add", far_addr, "dev", &b],
        vec![
            "ip",
            "-n",
            &near.ns,
            "link",
            "set",
            &a,
            "up",
            "multicast",
            "on",
        ],
        vec![
            "ip",
            "-n",
            &far.ns,
            "link",
            "set",
            &b,
            "up",
            "multicast",
            "on",
        ],
    ];
    if multicast {
        // The far host's multicast goes over the veth, not its own loopback.
        steps.push(vec![
            "ip",
            "-n",
            &far.ns,
            "route",
            "replace",
            "224.0.0.0/4",
            "dev",
            &b,
        ]);
    }
    for step in steps {
        run(&step).map_err(anyhow::Error::msg)?;
    }
    Ok((a, b))
}

/// The `[security]` table of device `id` in `fleet` (a [`Rig::fleet`]), empty without one.
pub fn security_toml(fleet: Option<&Path>, id: i64) -> String {
    fleet.map_or_else(String::new, |f| {
        format!("[security]\ndir = {:?}\n", f.join(id.to_string()))
    })
}

/// One output of the vehicle's record.
#[derive(Debug, Clone)]
pub struct Out {
    /// Wall-clock time of the output, µs since the Unix epoch.
    pub wall_us: u64,
    /// `apply` or `safe`.
    pub action: String,
    /// The owning device (`None`: the failsafe).
    pub owner: Option<i64>,
    /// The applied throttle, if values were applied.
    pub throttle: Option<i64>,
}

/// Every output recorded so far in the vehicle's `--record` file.
pub fn records(path: &Path) -> Vec<Out> {
    let mut follow = Follow::new(path);
    follow.poll();
    follow.lines.iter().map(out).collect()
}

fn out(v: &Value) -> Out {
    Out {
        wall_us: v["wall_us"].as_u64().unwrap_or(0),
        action: v["action"].as_str().unwrap_or("").to_string(),
        owner: v["owner"].as_i64(),
        throttle: v["throttle"].as_i64(),
    }
}

/// Waits until the vehicle applies a command from `owner` (or, for `None`, goes safe under the
/// failsafe) after `since_us` (wall clock); returns that output.
pub fn wait_for_output(record: &Path, owner: Option<i64>, since_us: u64) -> Result<Out, String> {
    let deadline = Instant::now() + PATIENCE;
    let mut follow = Follow::new(record);
    loop {
        follow.poll();
        if let Some(hit) = follow.find_since(since_us, |v| {
            v["owner"].as_i64() == owner && (v["action"] == "apply") == owner.is_some()
        }) {
            return Ok(out(hit));
        }
        if Instant::now() > deadline {
            return Err(format!(
                "no output from {owner:?} after {since_us}; last outputs: {:?}",
                follow
                    .lines
                    .iter()
                    .rev()
                    .take(5)
                    .map(out)
                    .collect::<Vec<_>>()
            ));
        }
        std::thread::sleep(Duration::from_millis(2));
    }
}

/// The complete JSON lines appended to a file since the last read (a line still being
/// written waits for its end); what is read is not kept.
#[derive(Debug)]
pub(crate) struct Appended {
    path: PathBuf,
    offset: u64,
    partial: String,
}

impl Appended {
    /// Reads `path` from its start (it need not exist yet).
    pub(crate) fn new(path: &Path) -> Appended {
        Appended {
            path: path.to_path_buf(),
            offset: 0,
            partial: String::new(),
        }
    }

    /// The lines appended since the last read, parsed (a line that does not parse is skipped).
    pub(crate) fn read(&mut self) -> Vec<Value> {
        use std::io::{Read, Seek, SeekFrom};
        let Ok(mut file) = std::fs::File::open(&self.path) else {
            return Vec::new();
        };
        if file.seek(SeekFrom::Start(self.offset)).is_err() {
            return Vec::new();
        }
        let mut fresh = String::new();
        let Ok(n) = file.read_to_string(&mut fresh) else {
            return Vec::new();
        };
        self.offset += n as u64;
        self.partial.push_str(&fresh);
        let mut lines = Vec::new();
        while let Some(end) = self.partial.find('\n') {
            let line: String = self.partial.drain(..=end).collect();
            if let Ok(v) = serde_json::from_str::<Value>(line.trim()) {
                lines.push(v);
            }
        }
        lines
    }
}

/// Follows a JSON-lines file another process appends to, parsing each line once (re-reading a
/// whole record every poll costs enough CPU to disturb what a benchmark measures).
#[derive(Debug)]
pub struct Follow {
    appended: Appended,
    /// Every complete line parsed so far, in file order.
    pub lines: Vec<Value>,
}

impl Follow {
    /// Follows `path` from its start (it need not exist yet).
    pub fn new(path: &Path) -> Follow {
        Follow {
            appended: Appended::new(path),
            lines: Vec::new(),
        }
    }

    /// The file followed.
    pub fn path(&self) -> &Path {
        &self.appended.path
    }

    /// Reads what was appended since the last poll.
    pub fn poll(&mut self) {
        let fresh = self.appended.read();
        self.lines.extend(fresh);
    }

    /// The first line at or after wall time `since_us` (lines are in time order) that matches.
    pub fn find_since(&self, since_us: u64, matches: impl Fn(&Value) -> bool) -> Option<&Value> {
        let start = self
            .lines
            .partition_point(|v| v["wall_us"].as_u64().unwrap_or(0) < since_us);
        self.lines[start..].iter().find(|v| matches(v))
    }
}

/// Waits until `rove status --events` output at `events` has listed every id of `ids`
/// (bounded by `patience`); the wall time of the event that completed the list.
pub fn wait_listed(
    events: &Path,
    ids: &std::collections::BTreeSet<i64>,
    patience: Duration,
) -> Result<u64, String> {
    let deadline = Instant::now() + patience;
    let mut follow = Follow::new(events);
    let mut seen = std::collections::BTreeSet::new();
    let mut read = 0;
    loop {
        follow.poll();
        for e in &follow.lines[read..] {
            let id = e["id"].as_i64().unwrap_or_default();
            if e["kind"] == "device"
                && ids.contains(&id)
                && seen.insert(id)
                && seen.len() == ids.len()
            {
                return Ok(e["wall_us"].as_u64().unwrap_or_default());
            }
        }
        read = follow.lines.len();
        if Instant::now() > deadline {
            return Err(format!(
                "{} listed only {} of {} devices",
                events.display(),
                seen.len(),
                ids.len()
            ));
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Microseconds since the Unix epoch, comparable with the record's `wall_us`.
pub fn wall_us() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_micros() as u64)
}

/// Runs `rove keys ARGS…` (it touches no network, so it runs outside any namespace).
///
/// # Errors
/// `rove` cannot be run or the command fails (its standard error is in the message: a build
/// without the `security` feature says so).
pub fn keys(rove: &Path, args: &[&str]) -> anyhow::Result<()> {
    let out = Command::new(rove).arg("keys").args(args).output()?;
    anyhow::ensure!(
        out.status.success(),
        "rove keys {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr).trim()
    );
    Ok(())
}
