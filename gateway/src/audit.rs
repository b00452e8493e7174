//! The audit of control on disk (issue 44; the chain itself: [`rove_core::audit`]).
//!
//! Each vehicle appends one JSON line per change of control to
//! `DIR/vehicle-ID-audit.jsonl`, where `DIR` is [`state_dir`] (`/var/lib/rove` under systemd's
//! `StateDirectory=rove`). Writes go to the file at once and are made durable (fdatasync, then
//! the checkpoint `vehicle-ID-audit.checkpoint`, replaced atomically) within a second: a power
//! cut loses at most the last second. The log is bounded: past [`MAX_FILE_BYTES`] it is
//! rotated to `vehicle-ID-audit.1.jsonl` (older ones shift up), and at most [`KEEP_ROTATED`]
//! rotated files are kept. The chain runs on across files.
//!
//! `rove audit [--verify]` prints the log (oldest first) and checks the chain and the
//! checkpoint: an edited, reordered, removed or cut-short log fails with the first break.

use anyhow::Context;
use rove_core::audit::{Chain, Checkpoint, Entry, Event, Verified, Who, Why};
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// A log file is rotated once it holds this much.
pub const MAX_FILE_BYTES: u64 = 1 << 20;
/// Rotated files kept (the oldest goes): the whole log stays under 9 MiB.
pub const KEEP_ROTATED: usize = 8;
/// What a power cut may lose at most.
pub const SYNC_EVERY: Duration = Duration::from_secs(1);

/// Where rove keeps what must survive a reboot: systemd's `StateDirectory=` (its first entry,
/// `$STATE_DIRECTORY`), else `/var/lib/rove` as root, else `$XDG_STATE_HOME/rove` or
/// `~/.local/state/rove`.
pub fn state_dir() -> Option<PathBuf> {
    if let Some(dirs) = std::env::var_os("STATE_DIRECTORY") {
        let first = std::env::split_paths(&dirs).next()?;
        return first.is_absolute().then_some(first);
    }
    if crate::dirs::is_root() {
        return Some(PathBuf::from("/var/lib/rove"));
    }
    let xdg = std::env::var_os("XDG_STATE_HOME").map(PathBuf::from);
    let home = std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".local/state"));
    xdg.or(home)
        .filter(|p| p.is_absolute())
        .map(|p| p.join("rove"))
}

/// The log's files of vehicle `id` in `dir`: the current one, then rotated `k`.
fn file(dir: &Path, id: i64, rotated: Option<usize>) -> PathBuf {
    match rotated {
        None => dir.join(format!("vehicle-{id}-audit.jsonl")),
        Some(k) => dir.join(format!("vehicle-{id}-audit.{k}.jsonl")),
    }
}

fn checkpoint_file(dir: &Path, id: i64) -> PathBuf {
    dir.join(format!("vehicle-{id}-audit.checkpoint"))
}

/// A vehicle's audit log, open for appending.
#[derive(Debug)]
pub struct AuditLog {
    dir: PathBuf,
    id: i64,
    file: File,
    bytes: u64,
    chain: Chain,
    /// Written since the last sync.
    dirty: bool,
    synced: Instant,
}

impl AuditLog {
    /// Opens vehicle `id`'s log in `dir` (created, mode 0700), going on from its last entry. An
    /// incomplete last line (a write cut by a power loss) is cut off.
    ///
    /// # Errors
    /// The directory or file cannot be created, read or written.
    pub fn open(dir: &Path, id: i64) -> anyhow::Result<AuditLog> {
        use std::os::unix::fs::DirBuilderExt;
        std::fs::DirBuilder::new()
            .recursive(true)
            .mode(0o700)
            .create(dir)
            .with_context(|| format!("audit directory {}", dir.display()))?;
        let path = file(dir, id, None);
        let text = std::fs::read(&path).unwrap_or_default();
        let complete = text.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
        let file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .with_context(|| format!("audit log {}", path.display()))?;
        if complete < text.len() {
            tracing::warn!(path = %path.display(), "audit log: an incomplete last line (cut by a power loss) removed");
            file.set_len(complete as u64)?;
        }
        let last = last_entry(&text[..complete]).or_else(|| last_rotated(dir, id));
        Ok(AuditLog {
            dir: dir.to_path_buf(),
            id,
            file,
            bytes: complete as u64,
            chain: Chain::after(last.as_ref()),
            dirty: false,
            synced: Instant::now(),
        })
    }

    /// The current file's path.
    pub fn path(&self) -> PathBuf {
        file(&self.dir, self.id, None)
    }

    /// Appends `event`; made durable within [`SYNC_EVERY`] (at once if the last sync was
    /// longer ago, else by [`AuditLog::tick`]).
    ///
    /// # Errors
    /// The file cannot be written, synced or rotated.
    pub fn record(&mut self, event: Event) -> anyhow::Result<()> {
        let entry = self.chain.append(event);
        let mut line = serde_json::to_vec(&entry)?;
        line.push(b'\n');
        self.file.write_all(&line)?;
        self.bytes += line.len() as u64;
        self.dirty = true;
        if self.bytes >= MAX_FILE_BYTES {
            self.rotate()?;
        } else if self.synced.elapsed() >= SYNC_EVERY {
            self.sync()?;
        }
        Ok(())
    }

    /// Syncs if something was written since the last sync (call at least once a second).
    ///
    /// # Errors
    /// As [`AuditLog::sync`].
    pub fn tick(&mut self) -> anyhow::Result<()> {
        match self.dirty {
            true => self.sync(),
            false => Ok(()),
        }
    }

    /// Makes everything written durable, then the checkpoint.
    ///
    /// # Errors
    /// The file cannot be synced, or the checkpoint written.
    pub fn sync(&mut self) -> anyhow::Result<()> {
        self.file.sync_data()?;
        if let Some(c) = self.chain.checkpoint() {
            let path = checkpoint_file(&self.dir, self.id);
            let tmp = path.with_extension("checkpoint.tmp");
            let mut f = File::create(&tmp)?;
            f.write_all(&serde_json::to_vec(&c)?)?;
            f.sync_data()?;
            std::fs::rename(&tmp, &path)?;
        }
        self.dirty = false;
        self.synced = Instant::now();
        Ok(())
    }

    /// The current file becomes rotated file 1 (older ones shift up, the oldest goes), and a
    /// new one is started; the chain runs on.
    fn rotate(&mut self) -> anyhow::Result<()> {
        self.sync()?;
        let _ = std::fs::remove_file(file(&self.dir, self.id, Some(KEEP_ROTATED)));
        for k in (1..KEEP_ROTATED).rev() {
            let from = file(&self.dir, self.id, Some(k));
            if from.exists() {
                std::fs::rename(&from, file(&self.dir, self.id, Some(k + 1)))?;
            }
        }
        std::fs::rename(self.path(), file(&self.dir, self.id, Some(1)))?;
        self.file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(self.path())?;
        self.bytes = 0;
        Ok(())
    }
}

/// A vehicle's audit as its control loop keeps it: the log, if it could be opened (an error is
/// in the journal, never a reason to leave the vehicle without its gateway), and how its
/// drivers' ids are known.
pub struct Recorder {
    log: Option<AuditLog>,
    vehicle: i64,
    /// Under DDS Security an id is believed only from a participant whose certificate names it.
    certifier: Option<rove_core::trust::Certifier>,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("log", &self.log)
            .field("vehicle", &self.vehicle)
            .field("secured", &self.certifier.is_some())
            .finish()
    }
}

impl Recorder {
    /// Vehicle `vehicle`'s log in [`state_dir`].
    pub fn open(vehicle: i64, certifier: Option<rove_core::trust::Certifier>) -> Recorder {
        let log = match state_dir() {
            Some(dir) => AuditLog::open(&dir, vehicle)
                .inspect_err(|e| tracing::error!("audit of control not kept: {e:#}"))
                .ok(),
            None => {
                tracing::error!(
                    "no state directory (STATE_DIRECTORY, /var/lib/rove or XDG_STATE_HOME): \
                     no audit of control"
                );
                None
            }
        };
        Recorder {
            log,
            vehicle,
            certifier,
        }
    }

    /// One that keeps nothing (the control loop's tests).
    pub fn none(vehicle: i64) -> Recorder {
        Recorder {
            log: None,
            vehicle,
            certifier: None,
        }
    }

    /// The current file, if a log is kept.
    pub fn path(&self) -> Option<PathBuf> {
        self.log.as_ref().map(AuditLog::path)
    }

    /// Appends who drives from `wall_us` on, and why. An error goes to the journal, once: the
    /// log is then closed.
    pub fn record(&mut self, wall_us: u64, owner: &rove_core::arbiter::Owner, why: Why) {
        let event = Event {
            wall_us,
            vehicle: self.vehicle,
            who: Who::of(owner, self.certifier.as_ref()),
            why,
        };
        self.keep(|log| log.record(event));
    }

    /// Made durable if anything was written since the last sync (call at least once a second).
    pub fn tick(&mut self) {
        self.keep(AuditLog::tick);
    }

    /// Made durable now (the stop).
    pub fn sync(&mut self) {
        self.keep(AuditLog::sync);
    }

    fn keep(&mut self, step: impl FnOnce(&mut AuditLog) -> anyhow::Result<()>) {
        if let Some(log) = self.log.as_mut()
            && let Err(e) = step(log)
        {
            tracing::error!("audit log {}: {e:#}; no more entries", log.path().display());
            self.log = None;
        }
    }
}

/// The last entry among `text`'s lines that reads.
fn last_entry(text: &[u8]) -> Option<Entry> {
    let text = String::from_utf8_lossy(text);
    (text.lines().rev()).find_map(|l| serde_json::from_str(l).ok())
}

/// The last entry of the newest rotated file (the current one was rotated and is empty).
fn last_rotated(dir: &Path, id: i64) -> Option<Entry> {
    last_entry(&std::fs::read(file(dir, id, Some(1))).ok()?)
}

/// Vehicle `id`'s log in `dir`, oldest line first, and its checkpoint.
///
/// # Errors
/// The current file cannot be read, or the checkpoint does not read.
pub fn read(dir: &Path, id: i64) -> anyhow::Result<(Vec<String>, Option<Checkpoint>)> {
    let mut lines = Vec::new();
    for k in (1..=KEEP_ROTATED).rev() {
        if let Ok(text) = std::fs::read_to_string(file(dir, id, Some(k))) {
            lines.extend(text.lines().map(str::to_string));
        }
    }
    let path = file(dir, id, None);
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("audit log {}", path.display()))?;
    lines.extend(text.lines().map(str::to_string));
    let checkpoint = match std::fs::read(checkpoint_file(dir, id)) {
        Ok(bytes) => Some(serde_json::from_slice(&bytes).context("audit checkpoint")?),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => return Err(e).context("audit checkpoint"),
    };
    Ok((lines, checkpoint))
}

/// Checks vehicle `id`'s log in `dir`.
///
/// # Errors
/// It cannot be read, or its chain is broken (the first break).
pub fn verify(dir: &Path, id: i64) -> anyhow::Result<Verified> {
    let (lines, checkpoint) = read(dir, id)?;
    Ok(rove_core::audit::verify(
        lines.iter().map(String::as_str),
        checkpoint.as_ref(),
    )?)
}

/// The vehicles with a log in `dir`.
pub fn vehicles(dir: &Path) -> Vec<i64> {
    let mut ids: Vec<i64> = (std::fs::read_dir(dir).into_iter().flatten().flatten())
        .filter_map(|e| {
            let name = e.file_name().into_string().ok()?;
            name.strip_prefix("vehicle-")?
                .strip_suffix("-audit.jsonl")?
                .parse()
                .ok()
        })
        .collect();
    ids.sort_unstable();
    ids
}

/// `wall_us` (µs since the Unix epoch) as `YYYY-MM-DD HH:MM:SS.mmm UTC`.
fn utc(wall_us: u64) -> String {
    let secs = wall_us / 1_000_000;
    let (days, rest) = ((secs / 86_400) as i64, secs % 86_400);
    // Days to a civil date (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02} {:02}:{:02}:{:02}.{:03} UTC",
        rest / 3600,
        rest / 60 % 60,
        rest % 60,
        wall_us / 1000 % 1000
    )
}

/// One entry as a line for people.
pub fn describe(e: &Entry) -> String {
    let when = utc(e.event.wall_us);
    let who = &e.event.who;
    let driver = match who.device {
        Some(id) => format!(
            "{id} ({}, strength {}, participant {})",
            who.identity,
            who.strength,
            who.participant.as_deref().unwrap_or("?")
        ),
        None => "failsafe".to_string(),
    };
    let why = serde_json::to_value(e.event.why)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_default();
    format!(
        "{:>6}  {when}  vehicle {}  {why:<11}  → {driver}",
        e.seq, e.event.vehicle
    )
}

/// `rove audit`: prints the log of `vehicle` (or of every vehicle with one in `dir`); with
/// `verify`, checks each chain and fails on the first break.
///
/// # Errors
/// No log, a log that does not read, or (`verify`) a broken chain.
pub fn cli(
    dir: Option<PathBuf>,
    vehicle: Option<i64>,
    verify_only: bool,
    json: bool,
) -> anyhow::Result<()> {
    let dir = dir
        .or_else(state_dir)
        .context("no state directory: give --dir")?;
    let ids = match vehicle {
        Some(id) => vec![id],
        None => vehicles(&dir),
    };
    anyhow::ensure!(!ids.is_empty(), "no audit log in {}", dir.display());
    for id in ids {
        let (lines, checkpoint) = read(&dir, id)?;
        if !verify_only {
            for line in &lines {
                match (json, serde_json::from_str::<Entry>(line)) {
                    (true, _) => println!("{line}"),
                    (false, Ok(e)) => println!("{}", describe(&e)),
                    (false, Err(_)) => println!("  (unreadable) {line}"),
                }
            }
        }
        let checked =
            rove_core::audit::verify(lines.iter().map(String::as_str), checkpoint.as_ref())
                .with_context(|| {
                    format!("vehicle {id}'s audit log in {} is broken", dir.display())
                })?;
        let since = match checked.first {
            Some(0) | None => String::from("from its start"),
            Some(n) => format!("from entry {n} (older entries rotated away)"),
        };
        let tail = match checked.after_checkpoint {
            0 => String::new(),
            n => format!("; {n} after the last checkpoint"),
        };
        eprintln!(
            "vehicle {id}: {} entries, chain intact {since}{tail}",
            checked.entries
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn event(k: u64) -> Event {
        Event {
            wall_us: 1_800_000_000_000_000 + k,
            vehicle: 100,
            who: Who {
                device: None,
                participant: None,
                identity: "failsafe".into(),
                strength: 0,
            },
            why: Why::Start,
        }
    }

    #[test]
    fn utc_dates() {
        assert_eq!(utc(0), "1970-01-01 00:00:00.000 UTC");
        // 2026-11-29 06:09:18.250 UTC
        assert_eq!(utc(1_795_932_558_250_000), "2026-11-29 06:09:18.250 UTC");
        assert_eq!(utc(951_782_400_000_000), "2000-02-29 00:00:00.000 UTC");
    }

    #[test]
    fn a_reopened_log_goes_on_with_its_chain_and_an_incomplete_line_is_cut() {
        let tmp = tempfile::tempdir().expect("a temporary directory");
        let dir = tmp.path().to_path_buf();
        let mut log = AuditLog::open(&dir, 100).expect("test step");
        log.record(event(0)).expect("test step");
        log.record(event(1)).expect("test step");
        log.sync().expect("test step");
        let path = log.path();
        drop(log);
        // A power cut in the middle of a write.
        let mut f = OpenOptions::new()
            .append(true)
            .open(&path)
            .expect("test step");
        f.write_all(b"{\"seq\":2,\"wall").expect("test step");
        let mut log = AuditLog::open(&dir, 100).expect("test step");
        log.record(event(2)).expect("test step");
        log.sync().expect("test step");
        let v = verify(&dir, 100).expect("test step");
        assert_eq!((v.entries, v.first, v.after_checkpoint), (3, Some(0), 0));
    }

    #[test]
    fn the_log_rotates_is_bounded_and_its_chain_runs_across_files() {
        let tmp = tempfile::tempdir().expect("a temporary directory");
        let dir = tmp.path().to_path_buf();
        let mut log = AuditLog::open(&dir, 7).expect("test step");
        // Each entry is ~200 bytes: enough for every rotated file and one more.
        let per_file = MAX_FILE_BYTES / 150;
        for k in 0..per_file * (KEEP_ROTATED as u64 + 2) {
            log.record(event(k)).expect("test step");
        }
        log.sync().expect("test step");
        assert!(!file(&dir, 7, Some(KEEP_ROTATED + 1)).exists());
        let v = verify(&dir, 7).expect("test step");
        assert!(
            v.first.is_some_and(|f| f > 0),
            "the oldest were rotated away: {v:?}"
        );
        assert_eq!(vehicles(&dir), vec![7]);
    }
}
