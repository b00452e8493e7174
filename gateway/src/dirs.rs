//! Where rove keeps what it keeps while the machine is up: the runtime directory (`rove
//! failsafe` reads a MAVLink vehicle's memory file from it after the vehicle died).

/// The directory for what a role keeps while the machine is up (`rove failsafe` reads it after
/// the role died), and where it came from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RuntimeDir {
    /// The directory.
    pub path: std::path::PathBuf,
    /// Why this one, for people (`rove doctor`).
    pub source: &'static str,
    /// Whether rove creates it (systemd creates its own).
    pub create: bool,
}

/// Where the runtime directory is (pure): systemd's `RuntimeDirectory=` (`runtime_directory`,
/// its first entry), else `xdg_runtime_dir/rove`, else, as root (a root shell, a container, a
/// custom init: no systemd, no login session), `/run/rove`. `None` for another user without
/// either: nothing is kept.
pub fn runtime_dir_from(
    runtime_directory: Option<&std::ffi::OsStr>,
    xdg_runtime_dir: Option<&std::ffi::OsStr>,
    root: bool,
) -> Option<RuntimeDir> {
    use std::path::{Path, PathBuf};
    if let Some(dirs) = runtime_directory {
        let first = std::env::split_paths(dirs).next()?;
        return first.is_absolute().then_some(RuntimeDir {
            path: first,
            source: "systemd's RuntimeDirectory=",
            create: false,
        });
    }
    if let Some(base) = xdg_runtime_dir.map(Path::new).filter(|b| b.is_absolute()) {
        return Some(RuntimeDir {
            path: base.join("rove"),
            source: "$XDG_RUNTIME_DIR",
            create: true,
        });
    }
    root.then(|| RuntimeDir {
        path: PathBuf::from("/run/rove"),
        source: "root without systemd or XDG_RUNTIME_DIR",
        create: true,
    })
}

/// Whether this process runs as root (its effective user owns `/proc/self`).
pub fn is_root() -> bool {
    std::fs::metadata("/proc/self").is_ok_and(|m| std::os::unix::fs::MetadataExt::uid(&m) == 0)
}

/// [`runtime_dir_from`] for this process's environment, not created.
pub fn runtime_location() -> Option<RuntimeDir> {
    runtime_dir_from(
        std::env::var_os("RUNTIME_DIRECTORY").as_deref(),
        std::env::var_os("XDG_RUNTIME_DIR").as_deref(),
        is_root(),
    )
}

/// The runtime directory ([`runtime_location`]), created (mode 0700) where rove makes its own.
/// `None` without one, or if it cannot be created.
pub fn runtime_dir() -> Option<std::path::PathBuf> {
    use std::os::unix::fs::DirBuilderExt;
    let dir = runtime_location()?;
    if !dir.create {
        return Some(dir.path);
    }
    match std::fs::DirBuilder::new().mode(0o700).create(&dir.path) {
        Ok(()) => Some(dir.path),
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Some(dir.path),
        Err(_) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::ffi::OsStr;

    /// Issue 49: as root with neither systemd's directory nor a login session's, the vehicle
    /// kept no memory file and `rove failsafe` waited for the autopilot's next HEARTBEAT.
    #[test]
    fn the_runtime_directory_falls_back_to_run_rove_for_root() {
        let dir = |r: Option<&str>, x: Option<&str>, root| {
            runtime_dir_from(r.map(OsStr::new), x.map(OsStr::new), root).map(|d| d.path)
        };
        let p = std::path::PathBuf::from;
        assert_eq!(dir(None, None, true), Some(p("/run/rove")));
        assert_eq!(
            dir(None, None, false),
            None,
            "another user has no /run of its own"
        );
        assert_eq!(
            dir(None, Some("/run/user/1000"), false),
            Some(p("/run/user/1000/rove"))
        );
        assert_eq!(
            dir(None, Some("/run/user/0"), true),
            Some(p("/run/user/0/rove"))
        );
        assert_eq!(
            dir(Some("/run/rove-vehicle:/run/other"), Some("/x"), true),
            Some(p("/run/rove-vehicle")),
            "systemd's first"
        );
        assert_eq!(dir(Some("relative"), None, true), None);
        assert_eq!(dir(None, Some("relative"), true), Some(p("/run/rove")));
        let systemd = runtime_dir_from(Some(OsStr::new("/run/rove-vehicle")), None, true);
        assert_eq!(systemd.map(|d| d.create), Some(false), "systemd made it");
    }
}
