//! What a running vehicle learned about its autopilot, kept on disk for `rove failsafe`.
//!
//! `rove failsafe` runs after the gateway died (systemd's `ExecStopPost`) and must put the
//! autopilot in its safe state at once. Alone it knows only the configuration: on a `udpin:`
//! link it has nobody to send to until the autopilot's next datagram (ArduPilot's UDP client
//! speaks first), and without `target_system` it cannot address a command before the next
//! HEARTBEAT (1 Hz). The running link therefore writes what it learned — the autopilot's UDP
//! address and its system and component ids — to a small file in the service's runtime
//! directory whenever it changes, and `rove failsafe` starts from it.
//!
//! The file is a few `key=value` lines; [`Learned::parse`] is pure and rejects anything it does
//! not expect, and a file for another endpoint (the configuration changed) is ignored.
//!
//! The running link hands what it learned to a [`Keeper`], which writes it on a thread of its
//! own (create, fsync, rename: never on the thread that reads the autopilot), newest first, and
//! only when it differs from what the file already holds — the file as loaded at start counts,
//! so a vehicle that restarts and hears the same autopilot writes nothing. `rove failsafe` only
//! reads the file: it leaves the running vehicle's record, and the directory, as they were.

use std::fmt;
use std::io::{self, Read, Write};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};
use tracing::{debug, warn};

/// The largest memory file read; a real one is under 100 bytes.
const MAX_FILE: u64 = 4096;

/// What the link learned about its autopilot.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Learned {
    /// The endpoint as configured (`Endpoint`'s display form): the file is for this link only.
    pub endpoint: String,
    /// The autopilot's address (a `udpin:` link: the sender of its datagrams).
    pub peer: Option<SocketAddr>,
    /// Its system id.
    pub system_id: u8,
    /// Its component id.
    pub component_id: u8,
}

impl fmt::Display for Learned {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "system {}/{}", self.system_id, self.component_id)?;
        if let Some(peer) = self.peer {
            write!(f, " at {peer}")?;
        }
        Ok(())
    }
}

impl Learned {
    /// The file's text.
    pub fn to_text(&self) -> String {
        let mut text = format!(
            "endpoint={}\nsystem={}\ncomponent={}\n",
            self.endpoint, self.system_id, self.component_id
        );
        if let Some(peer) = self.peer {
            text.push_str(&format!("peer={peer}\n"));
        }
        text
    }

    /// Parses a file's text (pure).
    ///
    /// # Errors
    /// A line that is not `key=value`, an unknown or repeated key, a bad value, a missing key.
    pub fn parse(text: &str) -> Result<Learned, String> {
        let (mut endpoint, mut peer, mut system, mut component) = (None, None, None, None);
        for (n, line) in text.lines().enumerate().map(|(i, l)| (i + 1, l.trim())) {
            if line.is_empty() {
                continue;
            }
            let (key, value) = line
                .split_once('=')
                .ok_or_else(|| format!("line {n}: not key=value"))?;
            let bad = |what: &str| format!("line {n}: {key}: not {what}");
            let slot_taken = match key {
                "endpoint" => endpoint.replace(value.to_string()).is_some(),
                "peer" => peer
                    .replace(value.parse::<SocketAddr>().map_err(|_| bad("an address"))?)
                    .is_some(),
                "system" => system
                    .replace(value.parse::<u8>().map_err(|_| bad("0..=255"))?)
                    .is_some(),
                "component" => component
                    .replace(value.parse::<u8>().map_err(|_| bad("0..=255"))?)
                    .is_some(),
                _ => return Err(format!("line {n}: unknown key {key:?}")),
            };
            if slot_taken {
                return Err(format!("line {n}: {key} given twice"));
            }
        }
        let missing = |key: &str| format!("no {key}");
        Ok(Learned {
            endpoint: endpoint.ok_or_else(|| missing("endpoint"))?,
            peer,
            system_id: system.ok_or_else(|| missing("system"))?,
            component_id: component.ok_or_else(|| missing("component"))?,
        })
    }

    /// Reads `path` if it exists and is for `endpoint`.
    ///
    /// # Errors
    /// The file cannot be read or does not parse, or it is for another endpoint (the message
    /// says why it is not used).
    pub fn load(path: &Path, endpoint: &str) -> Result<Option<Learned>, String> {
        let file = match std::fs::File::open(path) {
            Ok(f) => f,
            Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(format!("{}: {e}", path.display())),
        };
        let mut text = String::new();
        file.take(MAX_FILE)
            .read_to_string(&mut text)
            .map_err(|e| format!("{}: {e}", path.display()))?;
        let learned = Learned::parse(&text).map_err(|e| format!("{}: {e}", path.display()))?;
        if learned.endpoint != endpoint {
            return Err(format!(
                "{}: written for {}, the configuration says {endpoint}",
                path.display(),
                learned.endpoint
            ));
        }
        Ok(Some(learned))
    }

    /// Writes the file whole (a temporary file renamed over it: a reader never sees half).
    ///
    /// # Errors
    /// The directory is not writable.
    pub fn store(&self, path: &Path) -> io::Result<()> {
        let tmp = temporary(path);
        let mut file = std::fs::File::create(&tmp)?;
        file.write_all(self.to_text().as_bytes())?;
        file.sync_data()?;
        drop(file);
        std::fs::rename(&tmp, path)
    }
}

/// The file [`Learned::store`] writes before renaming it over `path`.
fn temporary(path: &Path) -> PathBuf {
    path.with_extension("tmp")
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Keeps the memory file up to date off the caller's thread (see the module's text).
#[derive(Debug)]
pub struct Keeper {
    shared: Arc<KeeperShared>,
}

#[derive(Debug)]
struct KeeperShared {
    path: PathBuf,
    state: Mutex<KeeperState>,
    wake: Condvar,
}

#[derive(Debug, Default)]
struct KeeperState {
    /// What the file holds (as loaded, or as last written).
    on_disk: Option<Learned>,
    /// The newest not written yet.
    queued: Option<Learned>,
    /// A write is under way.
    busy: bool,
    /// The owner is gone: write what is queued, then end.
    stop: bool,
    /// A failed write was logged (once).
    warned: bool,
}

impl Keeper {
    /// A keeper of `path`, which holds `on_disk` (as loaded). A temporary file a killed writer
    /// left behind is removed.
    ///
    /// # Errors
    /// The writer thread cannot be spawned.
    pub fn start(path: PathBuf, on_disk: Option<Learned>) -> io::Result<Keeper> {
        let _ = std::fs::remove_file(temporary(&path));
        let shared = Arc::new(KeeperShared {
            path,
            state: Mutex::new(KeeperState {
                on_disk,
                ..KeeperState::default()
            }),
            wake: Condvar::new(),
        });
        let for_thread = Arc::clone(&shared);
        std::thread::Builder::new()
            .name("rove-mavlink-keep".into())
            .spawn(move || write_loop(&for_thread))?;
        Ok(Keeper { shared })
    }

    /// Has `learned` written unless the file holds it already; returns at once.
    pub fn keep(&self, learned: Learned) {
        let mut s = lock(&self.shared.state);
        if s.on_disk.as_ref() == Some(&learned) {
            // Newer than anything queued, and already there.
            s.queued = None;
            return;
        }
        if s.queued.as_ref() != Some(&learned) {
            s.queued = Some(learned);
            self.shared.wake.notify_all();
        }
    }

    /// Waits until nothing is queued or being written, at most `limit`; whether it got there.
    pub fn wait_idle(&self, limit: Duration) -> bool {
        let deadline = Instant::now() + limit;
        let mut s = lock(&self.shared.state);
        while s.queued.is_some() || s.busy {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return false;
            }
            s = self
                .shared
                .wake
                .wait_timeout(s, left)
                .unwrap_or_else(PoisonError::into_inner)
                .0;
        }
        true
    }
}

impl Drop for Keeper {
    fn drop(&mut self) {
        lock(&self.shared.state).stop = true;
        self.shared.wake.notify_all();
    }
}

fn write_loop(shared: &KeeperShared) {
    let mut s = lock(&shared.state);
    loop {
        let Some(learned) = s.queued.take() else {
            if s.stop {
                return;
            }
            s = shared.wake.wait(s).unwrap_or_else(PoisonError::into_inner);
            continue;
        };
        s.busy = true;
        drop(s);
        let written = learned.store(&shared.path);
        s = lock(&shared.state);
        s.busy = false;
        match written {
            Ok(()) => {
                debug!(path = %shared.path.display(), %learned, "mavlink: kept what the link learned");
                s.on_disk = Some(learned);
            }
            Err(e) => {
                let _ = std::fs::remove_file(temporary(&shared.path));
                if !std::mem::replace(&mut s.warned, true) {
                    warn!(
                        path = %shared.path.display(),
                        error = %e,
                        "mavlink: cannot keep the autopilot's address and ids for `rove failsafe` \
                         (it will wait for the autopilot instead)"
                    );
                }
            }
        }
        shared.wake.notify_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn learned(peer: Option<&str>) -> Learned {
        Learned {
            endpoint: "udpin:127.0.0.1:14550".into(),
            peer: peer.map(|p| p.parse().expect("address")),
            system_id: 1,
            component_id: 1,
        }
    }

    #[test]
    fn round_trips_with_and_without_a_peer() {
        for l in [learned(Some("127.0.0.1:40123")), learned(None)] {
            assert_eq!(Learned::parse(&l.to_text()), Ok(l));
        }
    }

    #[test]
    fn rejects_what_it_does_not_expect() {
        let ok = learned(Some("127.0.0.1:40123")).to_text();
        for (text, why) in [
            (format!("{ok}extra=1\n"), "unknown key"),
            (format!("{ok}system=2\n"), "given twice"),
            (ok.replace("system=1", "system=256"), "0..=255"),
            (ok.replace("127.0.0.1:40123", "nowhere"), "an address"),
            (ok.replace("component=1\n", ""), "no component"),
            ("garbage".into(), "not key=value"),
        ] {
            let e = Learned::parse(&text).expect_err(&text);
            assert!(e.contains(why), "{text:?}: {e}");
        }
    }

    #[test]
    fn a_file_for_another_endpoint_or_none_at_all_is_not_used() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("learned");
        assert_eq!(Learned::load(&path, "udpin:127.0.0.1:14550"), Ok(None));
        let l = learned(Some("127.0.0.1:40123"));
        l.store(&path).expect("stored");
        assert_eq!(Learned::load(&path, "udpin:127.0.0.1:14550"), Ok(Some(l)));
        let e = Learned::load(&path, "tcpout:127.0.0.1:5760").expect_err("other endpoint");
        assert!(e.contains("written for udpin"), "{e}");
        std::fs::write(&path, vec![b'x'; 10_000]).expect("written");
        assert!(Learned::load(&path, "udpin:127.0.0.1:14550").is_err());
    }

    fn modified(path: &Path) -> std::time::SystemTime {
        std::fs::metadata(path)
            .and_then(|m| m.modified())
            .expect("the file's time")
    }

    /// Issue 50: the keeper writes only what the file does not hold yet — the file as loaded
    /// counts — and leaves no temporary file behind, a stale one included.
    #[test]
    fn the_keeper_writes_only_changes_and_leaves_nothing_else() {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("vehicle-100-mavlink");
        let l = learned(Some("127.0.0.1:40123"));
        l.store(&path).expect("stored");
        std::fs::write(temporary(&path), "half a file").expect("written");
        let before = modified(&path);
        let on_disk = Learned::load(&path, &l.endpoint).expect("readable");
        let keeper = Keeper::start(path.clone(), on_disk).expect("keeper");
        keeper.keep(l.clone());
        assert!(keeper.wait_idle(Duration::from_secs(10)));
        assert_eq!(
            modified(&path),
            before,
            "the same contents are not written again"
        );
        let listing = |dir: &Path| -> Vec<String> {
            let mut names: Vec<String> = std::fs::read_dir(dir)
                .expect("listing")
                .filter_map(|e| e.ok().map(|e| e.file_name().to_string_lossy().into_owned()))
                .collect();
            names.sort();
            names
        };
        assert_eq!(listing(dir.path()), ["vehicle-100-mavlink"]);
        // A change is written; the newest of several wins; back to the file's is nothing.
        let moved = learned(Some("127.0.0.1:40124"));
        keeper.keep(learned(Some("127.0.0.1:40999")));
        keeper.keep(moved.clone());
        assert!(keeper.wait_idle(Duration::from_secs(10)));
        assert_eq!(Learned::load(&path, &l.endpoint), Ok(Some(moved.clone())));
        let after = modified(&path);
        keeper.keep(moved);
        assert!(keeper.wait_idle(Duration::from_secs(10)));
        assert_eq!(modified(&path), after);
        assert_eq!(listing(dir.path()), ["vehicle-100-mavlink"]);
    }
}
