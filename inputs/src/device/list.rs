//! Listing evdev devices for `rove inputs list`: each node's name, stable links, kind, axes
//! and keys ([`DeviceSummary`]), or why it could not be opened ([`ListedDevice`]).

use super::INPUT_DIR;
use super::choose::{DeviceKind, event_nodes, kind_of};
use crate::codes::{abs_name, key_name};
use crate::curve::AbsState;
use evdev::raw_stream::RawDevice;
use std::fmt;
use std::path::{Path, PathBuf};

/// One device as `rove inputs list` shows it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceSummary {
    /// `/dev/input/eventN`.
    pub path: PathBuf,
    /// by-id and by-path links to it (stable names for configs).
    pub links: Vec<PathBuf>,
    /// The device's name.
    pub name: String,
    /// What it looks like.
    pub kind: DeviceKind,
    /// Absolute axes with their absinfo.
    pub axes: Vec<(u16, AbsState)>,
    /// Keys and buttons.
    pub keys: Vec<u16>,
}

impl fmt::Display for DeviceSummary {
    /// Several lines: path and name, links, axes with ranges, buttons.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{}  {:?}  ({})",
            self.path.display(),
            self.name,
            self.kind
        )?;
        for link in &self.links {
            writeln!(f, "  link: {}", link.display())?;
        }
        for (code, s) in &self.axes {
            writeln!(
                f,
                "  axis {:<12} value {:>6}  range {}..{}  flat {}  fuzz {}",
                abs_name(*code),
                s.value,
                s.minimum,
                s.maximum,
                s.flat,
                s.fuzz
            )?;
        }
        if !self.keys.is_empty() {
            let names: Vec<String> = self.keys.iter().map(|k| key_name(*k)).collect();
            writeln!(f, "  keys: {}", names.join(" "))?;
        }
        Ok(())
    }
}

/// A device node and what could be read from it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ListedDevice {
    /// `/dev/input/eventN`.
    pub path: PathBuf,
    /// Its capabilities, or why it could not be opened (often: permission denied; add the user
    /// to the `input` group).
    pub summary: Result<DeviceSummary, String>,
}

/// Every evdev device under [`INPUT_DIR`] (empty when there is none, as on this CI machine).
pub fn list_devices() -> Vec<ListedDevice> {
    list_devices_in(Path::new(INPUT_DIR))
}

/// Every evdev device under `dir`.
pub fn list_devices_in(dir: &Path) -> Vec<ListedDevice> {
    let links = stable_links(dir);
    event_nodes(dir)
        .into_iter()
        .map(|path| {
            let summary = RawDevice::open(&path)
                .map_err(|e| e.to_string())
                .and_then(|dev| summarise(&path, &dev, &links));
            ListedDevice { path, summary }
        })
        .collect()
}

/// (link, target) pairs from `dir/by-id` and `dir/by-path`.
fn stable_links(dir: &Path) -> Vec<(PathBuf, PathBuf)> {
    let mut out = Vec::new();
    for sub in ["by-id", "by-path"] {
        let Ok(entries) = std::fs::read_dir(dir.join(sub)) else {
            continue;
        };
        for entry in entries.flatten() {
            if let Ok(target) = std::fs::canonicalize(entry.path()) {
                out.push((entry.path(), target));
            }
        }
    }
    out.sort();
    out
}

fn summarise(
    path: &Path,
    dev: &RawDevice,
    links: &[(PathBuf, PathBuf)],
) -> Result<DeviceSummary, String> {
    let canonical = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf());
    let axes = dev
        .get_absinfo()
        .map_err(|e| format!("reading absinfo: {e}"))?
        .map(|(code, info)| (code.0, AbsState::from(info)))
        .collect();
    Ok(DeviceSummary {
        path: path.to_path_buf(),
        links: links
            .iter()
            .filter(|(_, target)| *target == canonical)
            .map(|(link, _)| link.clone())
            .collect(),
        name: dev.name().unwrap_or("unnamed").to_string(),
        kind: kind_of(dev),
        axes,
        keys: dev
            .supported_keys()
            .map(|k| k.iter().map(|k| k.0).collect())
            .unwrap_or_default(),
    })
}
