//! Revoked sites (`rove keys revoke --site`, docs/remote.md). Zenoh's TLS checks a site's
//! certificate against the fleet CA but reads no revocation list, so the fleet CA also signs the
//! list of revoked site *names* (`revoked-sites.p7s`), copied beside `[zenoh] ca`. A bridge
//! refuses a site it names: left out of the link's access control at start, cut off (its
//! devices leave, nothing it sends is taken) when the file changes while running. A revoked
//! name stays refused: a site issued again gets a new name.

use super::Bridge;
use crate::config::ZenohLink;
use rove_core::site::{Policy, SiteName};
use std::collections::BTreeSet;
use std::path::PathBuf;
use std::time::{Duration, Instant, SystemTime};
use tracing::{error, warn};

/// How often the file's modification time is looked at.
const CHECK_EVERY: Duration = Duration::from_secs(2);

/// The revoked site names this bridge knows, and where they come from.
#[derive(Debug)]
pub(super) struct Revocations {
    file: PathBuf,
    ca: PathBuf,
    /// The modification time of the file last read (`None`: no file).
    read: Option<SystemTime>,
    names: BTreeSet<String>,
    checked: Instant,
}

impl Revocations {
    /// The names in the file beside `link.ca`, if there is one.
    ///
    /// # Errors
    /// The file does not read or is not signed by the fleet CA, this site (`me`) is revoked,
    /// or this build cannot check the signature.
    pub(super) fn load(link: &ZenohLink, me: &SiteName) -> anyhow::Result<Revocations> {
        let dir = link.ca.parent().unwrap_or(std::path::Path::new("."));
        let mut revoked = Revocations {
            file: dir.join(FILE),
            ca: link.ca.clone(),
            read: None,
            names: BTreeSet::new(),
            checked: Instant::now(),
        };
        if let Some((read, names)) = revoked.read()? {
            (revoked.read, revoked.names) = (Some(read), names);
        }
        anyhow::ensure!(
            !revoked.names.contains(me.as_str()),
            "site {me}'s certificate is revoked ({})",
            revoked.file.display()
        );
        Ok(revoked)
    }

    /// `policy` without the revoked sites (each logged).
    pub(super) fn apply(&self, mut policy: Policy) -> Policy {
        policy.peers.retain(|peer| {
            let revoked = self.names.contains(peer.name.as_str());
            if revoked {
                error!(site = %peer.name, file = %self.file.display(), "site revoked: refused on the link");
            }
            !revoked
        });
        policy
    }

    /// The file's modification time and names, if it exists.
    fn read(&self) -> anyhow::Result<Option<(SystemTime, BTreeSet<String>)>> {
        let Ok(meta) = std::fs::metadata(&self.file) else {
            return Ok(None);
        };
        let modified = meta.modified()?;
        #[cfg(feature = "security")]
        return Ok(Some((
            modified,
            crate::certs::revoked_sites(&self.ca, &self.file)?,
        )));
        #[cfg(not(feature = "security"))]
        {
            let _ = (modified, &self.ca);
            anyhow::bail!(
                "{}: this rove was built without the `security` feature and cannot check it",
                self.file.display()
            )
        }
    }

    /// Names revoked since the last look, if the file changed (at most every [`CHECK_EVERY`]).
    /// A changed file that does not verify is logged and the names known are kept.
    fn newly_revoked(&mut self) -> Vec<String> {
        if self.checked.elapsed() < CHECK_EVERY {
            return Vec::new();
        }
        self.checked = Instant::now();
        let modified = std::fs::metadata(&self.file)
            .and_then(|m| m.modified())
            .ok();
        if modified.is_none() || modified == self.read {
            return Vec::new();
        }
        match self.read() {
            Ok(Some((read, names))) => {
                self.read = Some(read);
                let new: Vec<String> = names.difference(&self.names).cloned().collect();
                self.names.extend(names);
                new
            }
            Ok(None) => Vec::new(),
            Err(e) => {
                warn!("revoked sites not read again, the names known are kept: {e:#}");
                self.read = modified;
                Vec::new()
            }
        }
    }
}

/// The file's name.
#[cfg(feature = "security")]
const FILE: &str = crate::certs::REVOKED_SITES_FILE;
#[cfg(not(feature = "security"))]
const FILE: &str = "revoked-sites.p7s";

impl Bridge {
    /// Cuts off every site revoked since the last look: its devices leave this site, and it is
    /// no longer a configured site (nothing it sends is taken, nothing goes to it).
    pub(super) fn cut_off_revoked(&mut self) {
        for name in self.revoked.newly_revoked() {
            let Some(peer) = self
                .policy
                .peers
                .iter()
                .position(|p| p.name.as_str() == name)
            else {
                continue;
            };
            let site = self.policy.peers.remove(peer).name;
            error!(%site, "site revoked: cut off, its devices leave this site");
            self.up.remove(&site);
            self.away.came(&site); // no grace: it leaves now
            self.reshow.remove(&site);
            self.drop_site(&site);
        }
    }
}
