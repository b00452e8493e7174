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

use std::fmt;
use std::io::{self, Read, Write};
use std::net::SocketAddr;
use std::path::Path;

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
        let tmp = path.with_extension("tmp");
        let mut file = std::fs::File::create(&tmp)?;
        file.write_all(self.to_text().as_bytes())?;
        file.sync_data()?;
        drop(file);
        std::fs::rename(&tmp, path)
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
}
