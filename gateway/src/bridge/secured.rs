//! A secured site (`[security]` in the bridge's file, docs/remote.md): the bridge joins its
//! site's network as the site, shows each device of another site under that device's proxy
//! certificate, and carries a local device's messages only from the participant holding the
//! device's own certificate.

use super::revoked::Revocations;
use crate::config::{BridgeConfig, Common};
use rove_core::arbiter::ParticipantId;
use rove_core::msg::DeviceId;
use rove_core::site::Policy;
use std::path::Path;

/// The revoked sites, the policy without them, and a secured site's identities.
pub(super) fn identities(
    config: &BridgeConfig,
) -> anyhow::Result<(Revocations, Policy, Option<Secured>)> {
    let revoked = Revocations::load(&config.link, &config.policy.me)?;
    let policy = revoked.apply(config.policy.clone());
    let secured = Secured::load(&config.common, &policy)?;
    Ok((revoked, policy, secured))
}

/// A secured bridge's identities, checked at start.
#[derive(Debug)]
pub(super) struct Secured {
    #[cfg(feature = "security")]
    identity: crate::certs::SiteIdentity,
    /// Without the `security` feature there is none ([`Secured::load`] fails).
    #[cfg(not(feature = "security"))]
    never: std::convert::Infallible,
}

impl Secured {
    /// The site's identities under `[security]` (`None` without): the bridge's own and a proxy
    /// certificate, at the configured level, for every id another site may speak for.
    ///
    /// # Errors
    /// The directory is incomplete or not this site's, an id has no proxy certificate or one of
    /// another level, or this build has no security.
    pub(super) fn load(common: &Common, policy: &Policy) -> anyhow::Result<Option<Secured>> {
        let Some(dir) = &common.security else {
            return Ok(None);
        };
        #[cfg(feature = "security")]
        {
            let identity = crate::certs::SiteIdentity::load(dir, &policy.me)?;
            for peer in &policy.peers {
                for &id in &peer.ids {
                    match identity.proxy(id) {
                        Some((_, level)) if level == peer.level => {}
                        Some((path, level)) => anyhow::bail!(
                            "[security] {}: the proxy certificate of site {}'s device {id} is \
                             for level {level:?}, the site's level is {:?} (issue it again: \
                             rove keys site --name {} --proxies {id} --level …)",
                            path.display(),
                            peer.name,
                            peer.level,
                            policy.me
                        ),
                        None => anyhow::bail!(
                            "[security] {}: no proxy certificate for site {}'s device {id} \
                             (rove keys site --name {} --proxies {id} --level {})",
                            dir.display(),
                            peer.name,
                            policy.me,
                            format!("{:?}", peer.level).to_lowercase()
                        ),
                    }
                }
            }
            tracing::info!(
                dir = %dir.display(),
                fleet = identity.fleet.fleet(),
                "secured site: the bridge joins as the site, shows each device of another \
                 site under its proxy certificate, and hears a device here only from its own \
                 certificate"
            );
            Ok(Some(Secured { identity }))
        }
        #[cfg(not(feature = "security"))]
        {
            let _ = policy;
            anyhow::bail!(
                "[security] {}: this rove was built without the `security` feature",
                dir.display()
            )
        }
    }

    /// The bridge's own participant's security directory.
    pub(super) fn own(&self) -> &Path {
        #[cfg(feature = "security")]
        return &self.identity.dds;
        #[cfg(not(feature = "security"))]
        match self.never {}
    }

    /// Device `id`'s proxy certificate directory, if the site has one.
    pub(super) fn proxy(&self, id: DeviceId) -> Option<&Path> {
        #[cfg(feature = "security")]
        return self.identity.proxy(id).map(|(path, _)| path);
        #[cfg(not(feature = "security"))]
        {
            let _ = id;
            match self.never {}
        }
    }

    /// Whether `participant` holds device `id`'s own certificate.
    pub(super) fn is_device(&self, id: DeviceId, participant: ParticipantId) -> bool {
        #[cfg(feature = "security")]
        return self.identity.fleet.speaks_for(id, participant)
            == rove_core::trust::Certified::Device;
        #[cfg(not(feature = "security"))]
        {
            let _ = (id, participant);
            match self.never {}
        }
    }
}
