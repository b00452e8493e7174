//! A site's identities (docs/remote.md): its bridge's certificate for the link between sites and,
//! for a secured site, its DDS identities. A secured bridge joins its site's DDS network as the
//! site (`dds/`, subject `O=<fleet>, CN=rove-site-NAME`), and shows each device of another site
//! under a *proxy certificate* the fleet CA issued for that device id (`proxies/ID/`, subject
//! `O=<fleet>, OU=rove-site-proxy-LEVEL, CN=rove-ID`). The site's devices believe a proxy
//! certificate for its id only, and a command under it only up to its level
//! ([`super::FleetIdentity::speaks_for`]): the trust rules and `[access]` hold as on one site
//! even if the bridge were wrong.

use super::{
    FleetIdentity, Lifetime, common_name, fleet_ca, fleet_domain, fleet_of, issue_identity,
    issue_tls, new_key, subject, write,
};
use anyhow::{Context, bail};
use openssl::nid::Nid;
use openssl::x509::{X509, X509Name, X509NameBuilder};
use rove_core::hierarchy::Level;
use rove_core::msg::DeviceId;
use rove_core::site::SiteName;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The organisational unit of a site proxy certificate at `level`.
fn proxy_unit(level: Level) -> &'static str {
    match level {
        Level::Remote => "rove-site-proxy-remote",
        Level::Stationary => "rove-site-proxy-stationary",
        Level::Mobile => "rove-site-proxy-mobile",
    }
}

/// The subject of the site proxy certificate for device `id` at `level`.
pub(super) fn proxy_subject(fleet: &str, id: DeviceId, level: Level) -> anyhow::Result<X509Name> {
    let mut name = X509NameBuilder::new()?;
    name.append_entry_by_nid(Nid::ORGANIZATIONNAME, fleet)?;
    name.append_entry_by_nid(Nid::ORGANIZATIONALUNITNAME, proxy_unit(level))?;
    name.append_entry_by_nid(Nid::COMMONNAME, &common_name(id))?;
    Ok(name.build())
}

/// Issues a site bridge's certificate for the link between sites (docs/remote.md), signed by
/// the fleet CA, subject `O=<fleet>, CN=rove-site-NAME`, for both ends of a TLS link (server
/// and client authentication), with the names and addresses in `hosts` as subject alternative
/// names. Writes `DIR/site-NAME/` (`cert.pem`, `key.pem`, and the fleet's `ca.cert.pem`): point
/// `[zenoh] certificate`, `key` and `ca` there. The other sites' bridges let the common name
/// speak only under the site's own name, and for the ids configured for it.
///
/// # Errors
/// `dir` holds no fleet, the files exist, or OpenSSL fails.
pub fn site(
    dir: &Path,
    name: &SiteName,
    hosts: &[String],
    lifetime: Lifetime,
) -> anyhow::Result<PathBuf> {
    use openssl::x509::extension::ExtendedKeyUsage;
    let (ca, ca_key) = fleet_ca(dir)?;
    let out = dir.join(format!("site-{name}"));
    if out.join("cert.pem").exists() {
        bail!("{} exists already", out.join("cert.pem").display());
    }
    std::fs::create_dir_all(&out).with_context(|| format!("create {}", out.display()))?;
    let subject_name = subject(&fleet_of(&ca)?, &name.common_name())?;
    let usage = ExtendedKeyUsage::new()
        .server_auth()
        .client_auth()
        .build()?;
    issue_tls(&out, (&ca, &ca_key), &subject_name, hosts, usage, lifetime)?;
    write(&out.join("ca.cert.pem"), &ca.to_pem()?, false)?;
    Ok(out)
}

/// Issues a secured site's DDS identities in `DIR/site-NAME/`: the bridge's own (`dds/`, made
/// once) and a proxy certificate at `level` for each of `ids` (`proxies/ID/`), the devices of
/// other sites this site's bridge shows here. Point the bridge's `[security] dir` at
/// `DIR/site-NAME`. Returns that directory.
///
/// # Errors
/// `dir` holds no fleet, an id is not positive or has a proxy certificate already, or a file
/// cannot be written.
pub fn site_proxies(
    dir: &Path,
    name: &SiteName,
    ids: &[DeviceId],
    level: Level,
    lifetime: Lifetime,
) -> anyhow::Result<PathBuf> {
    let fleet = fleet_of(&fleet_ca(dir)?.0)?;
    let domain = fleet_domain(dir)?;
    let out = dir.join(format!("site-{name}"));
    for &id in ids {
        if id <= 0 {
            bail!("device id {id}: must be positive");
        }
        let path = out.join("proxies").join(id.to_string());
        if path.join("cert.pem").exists() {
            bail!("{} exists already", path.display());
        }
    }
    let own = out.join("dds");
    if !own.join("cert.pem").exists() {
        let cn = name.common_name();
        let grant = format!("CN={cn},O={fleet}");
        issue_key_and_identity(
            dir,
            &own,
            (&subject(&fleet, &cn)?, &grant),
            lifetime,
            domain,
        )?;
    }
    for &id in ids {
        let path = out.join("proxies").join(id.to_string());
        let grant = format!("CN={},OU={},O={fleet}", common_name(id), proxy_unit(level));
        let name = proxy_subject(&fleet, id, level)?;
        issue_key_and_identity(dir, &path, (&name, &grant), lifetime, domain)?;
    }
    Ok(out)
}

/// A new key in `out` and a DDS identity for it ([`issue_identity`]).
fn issue_key_and_identity(
    dir: &Path,
    out: &Path,
    subject: (&X509Name, &str),
    lifetime: Lifetime,
    domain: u16,
) -> anyhow::Result<()> {
    let key = new_key()?;
    issue_identity(dir, out, subject, &key, lifetime, domain)?;
    write(&out.join("key.pem"), &key.private_key_to_pem_pkcs8()?, true)
}

/// A secured bridge's DDS identities, checked at start: its own directory, and the proxy
/// certificate (directory and level) of each id it may show.
#[derive(Debug)]
pub struct SiteIdentity {
    /// Who speaks for which id on this site's network.
    pub fleet: FleetIdentity,
    /// The bridge's own participant's directory (`dds/`).
    pub dds: PathBuf,
    proxies: BTreeMap<DeviceId, (PathBuf, Level)>,
}

impl SiteIdentity {
    /// Reads `DIR` (`DIR/site-NAME` of `rove keys site --proxies`) for site `name`.
    ///
    /// # Errors
    /// A file is missing, the bridge's certificate is not site `name`'s, or a proxy
    /// certificate is not for the id its directory names.
    pub fn load(dir: &Path, name: &SiteName) -> anyhow::Result<SiteIdentity> {
        let dds = dir.join("dds");
        let fleet = super::check_identity_dir(&dds, &name.common_name())?;
        let mut proxies = BTreeMap::new();
        let listing = std::fs::read_dir(dir.join("proxies"));
        for entry in listing.into_iter().flatten().flatten() {
            let path = entry.path();
            let Some(id) = (entry.file_name().to_str()).and_then(|n| n.parse::<DeviceId>().ok())
            else {
                continue;
            };
            super::check_identity_dir(&path, &common_name(id))?;
            let cert = X509::from_pem(&std::fs::read(path.join("cert.pem"))?)?;
            let unit = (cert
                .subject_name()
                .entries_by_nid(Nid::ORGANIZATIONALUNITNAME)
                .next())
            .map(|e| e.data().to_string())
            .transpose()?
            .unwrap_or_default();
            let Some(level) = Level::ALL.into_iter().find(|l| proxy_unit(*l) == unit) else {
                bail!(
                    "[security] {}: not a site proxy certificate (OU {unit:?})",
                    path.display()
                );
            };
            proxies.insert(id, (path, level));
        }
        Ok(SiteIdentity {
            fleet,
            dds,
            proxies,
        })
    }

    /// Device `id`'s proxy certificate: its directory and level.
    pub fn proxy(&self, id: DeviceId) -> Option<(&Path, Level)> {
        (self.proxies.get(&id)).map(|(path, level)| (path.as_path(), *level))
    }
}
