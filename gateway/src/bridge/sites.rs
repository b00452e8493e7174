//! Other sites coming and going on the link. A site whose link went keeps its devices here for
//! [`GRACE`](rove_core::site::absence::GRACE): a link that drops and is back within
//! milliseconds does not take every one of its devices off this site and make them again
//! ([`rove_core::site::absence`]). Safety does not wait for it: a cut stops the streams.

use super::{Bridge, RESHOW};
use rove_core::site::SiteName;
use std::time::Instant;
use tracing::info;

impl Bridge {
    /// `site`'s bridge came (`up`) or went (its token withdrawn, or its link lost).
    pub(super) async fn site(&mut self, site: SiteName, up: bool) {
        if up {
            if self.away.came(&site) {
                info!(%site, "site back: its devices stayed here");
            } else {
                info!(%site, "site up");
            }
            self.up.insert(site.clone());
            self.show_all(&site).await;
            // Again a second later: its subscription may not have been routed yet when its
            // token arrived.
            self.reshow.insert(site, Instant::now() + RESHOW);
        } else {
            info!(
                %site,
                grace_ms = rove_core::site::absence::GRACE.as_millis() as u64,
                "site gone: its devices leave this site unless it is back within the grace"
            );
            self.up.remove(&site);
            self.away.went(&site, self.clock.now());
        }
    }

    /// The sites away for the whole grace: their devices leave this site.
    pub(super) fn leave_due(&mut self) {
        for site in self.away.due(self.clock.now()) {
            info!(%site, "site still gone: its devices leave this site");
            self.drop_site(&site);
        }
    }
}
