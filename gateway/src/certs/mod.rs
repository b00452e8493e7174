//! `rove keys`: a fleet's DDS Security files (docs/security.md), and the device id a secured
//! participant speaks for.
//!
//! Layout of a fleet directory:
//! - `ca.cert.pem`, `ca.key.pem`: the fleet CA. It is both the identity CA (it signs every
//!   device certificate) and the permissions CA (it signs the governance and every permissions
//!   document): one fleet, one root of trust.
//! - `governance.p7s`: the domain's rules, S/MIME signed: no unauthenticated participant, join
//!   access control, every topic read/write access controlled, and every RTPS message
//!   (discovery, liveliness, data) encrypted with origin authentication as a whole.
//!   Submessage-level protection (discovery, liveliness, metadata or data kinds other than
//!   NONE) is left off: with rustdds 0.15.1, two rove processes then completed their endpoint
//!   key exchange in only 4 of 10 runs, against 13 of 13 with RTPS protection alone
//!   (docs/security.md).
//! - `ID/`: what device `ID` needs, under the file names rustdds (and ROS 2) expect, so that
//!   `[security] dir` names one directory: `cert.pem` (subject `O=<fleet>, CN=rove-ID`),
//!   `key.pem` (PKCS#8 PEM, unencrypted: rustdds ignores key passwords; mode 0600),
//!   `permissions.p7s` (publish and subscribe rove's three topics in the fleet's domain), and
//!   copies of the CA (`identity_ca.cert.pem`, `permissions_ca.cert.pem`) and the governance.
//!
//! Keys are EC P-256 and signatures SHA-256, as rustdds's builtin plugins expect. The files are
//! made with the OpenSSL library rustdds's security links anyway; no second crypto stack.
//!
//! # Which id a participant speaks for
//! Under DDS Security the first six bytes of a participant's GUID prefix are derived from the
//! SHA-256 of its certificate's subject (DDS Security §9.3.3; rustdds checks it for every remote
//! participant during authentication). [`FleetIdentity::speaks_for`] recomputes that prefix for
//! the subject `rove keys` gives device `id`, so a participant may speak only for the id in its
//! certificate.

pub mod cli;
mod enrol;
use anyhow::{Context, anyhow, bail};
use openssl::bn::{BigNum, MsbOption};
use openssl::ec::{EcGroup, EcKey};
use openssl::hash::{MessageDigest, hash};
use openssl::nid::Nid;
use openssl::pkcs7::{Pkcs7, Pkcs7Flags};
use openssl::pkey::{PKey, Private};
use openssl::stack::Stack;
use openssl::x509::extension::{BasicConstraints, KeyUsage};
use openssl::x509::{X509, X509Builder, X509Name, X509NameBuilder};
use rove_core::arbiter::ParticipantId;
use rove_core::hierarchy::Level;
use rove_core::msg::DeviceId;
use rove_core::trust::Certified;
use std::path::{Path, PathBuf};

mod lifetime;
mod revocation;
mod site;

pub use enrol::{REQUEST_FILE, request, sign_request};
pub use lifetime::{BACKDATE_S, Expiry, Issued, Lifetime, WARN_DAYS, list};
pub use revocation::{CRL_FILE, REVOKED_SITES_FILE, Revoked, revoke, revoke_site, revoked_sites};
pub use site::{SiteIdentity, site, site_proxies};

/// The topics every device may publish and subscribe.
const TOPICS: [&str; 4] = [
    "DeviceInfo",
    "ControlCommand",
    "RequestControl",
    "VehicleStatus",
];

/// The common name of device `id`'s certificate.
pub fn common_name(id: DeviceId) -> String {
    format!("rove-{id}")
}

/// Creates a fleet in `dir`: its CA and its governance for DDS domain `domain`.
///
/// # Errors
/// `dir` already holds a fleet, or a file cannot be written, or OpenSSL fails.
pub fn init(dir: &Path, fleet: &str, domain: u16) -> anyhow::Result<()> {
    if dir.join("ca.cert.pem").exists() {
        bail!("{} already holds a fleet (ca.cert.pem)", dir.display());
    }
    if fleet.is_empty() || fleet.contains([',', '=', '+', '<', '>', '#', ';', '"', '\\']) {
        bail!("fleet name {fleet:?}: use letters, digits, spaces, '-', '_' or '.'");
    }
    std::fs::create_dir_all(dir).with_context(|| format!("create {}", dir.display()))?;
    let key = new_key()?;
    let name = subject(fleet, "rove fleet CA")?;
    let mut cert = builder(&name, &name, &key, Lifetime::CA)?;
    cert.append_extension(BasicConstraints::new().critical().ca().build()?)?;
    cert.append_extension(
        KeyUsage::new()
            .critical()
            .key_cert_sign()
            .crl_sign()
            .build()?,
    )?;
    cert.sign(&key, MessageDigest::sha256())?;
    let cert = cert.build();
    write(&dir.join("ca.cert.pem"), &cert.to_pem()?, false)?;
    write(
        &dir.join("ca.key.pem"),
        &key.private_key_to_pem_pkcs8()?,
        true,
    )?;
    let governance = governance_xml(domain);
    write(
        &dir.join("governance.p7s"),
        &sign(&cert, &key, &governance)?,
        false,
    )?;
    revocation::write_list(dir, &cert, &key, &[])?;
    write(&dir.join("domain"), domain.to_string().as_bytes(), false)
}

/// Issues device `id`'s certificate (valid for `lifetime`), key and permissions in `dir/ID/`;
/// returns that directory. With `renew`, an existing device gets a new key and certificate.
///
/// # Errors
/// `dir` holds no fleet, the device exists already (and not `renew`), or a file cannot be
/// read or written.
pub fn add(dir: &Path, id: DeviceId, lifetime: Lifetime, renew: bool) -> anyhow::Result<PathBuf> {
    let key = new_key()?;
    let out = issue_device(dir, id, &key, lifetime, renew, &DEVICE_FILES)?;
    write(&out.join("key.pem"), &key.private_key_to_pem_pkcs8()?, true)?;
    Ok(out)
}

/// Issues device `id`'s certificate for `public_key`, and its permissions, in `dir/ID/` with
/// copies of the CA, the governance and the revocation list (everything a device needs but its
/// private key); returns that directory. An existing device's `replaced` files are removed
/// first, with `renew`.
///
/// # Errors
/// As [`add`].
fn issue_device<K: openssl::pkey::HasPublic>(
    dir: &Path,
    id: DeviceId,
    public_key: &openssl::pkey::PKeyRef<K>,
    lifetime: Lifetime,
    renew: bool,
    replaced: &[&str],
) -> anyhow::Result<PathBuf> {
    if id <= 0 {
        bail!("device id {id}: must be positive");
    }
    let domain = fleet_domain(dir)?;
    let fleet = fleet_of(&fleet_ca(dir)?.0)?;
    let out = dir.join(id.to_string());
    if out.join("cert.pem").exists() {
        if !renew {
            bail!(
                "device {id} exists already in {} (renew it with --renew)",
                out.display()
            );
        }
        for name in replaced {
            let path = out.join(name);
            if path.exists() {
                std::fs::remove_file(&path)
                    .with_context(|| format!("remove {}", path.display()))?;
            }
        }
    }
    let name = subject(&fleet, &common_name(id))?;
    let grant = format!("CN={},O={fleet}", common_name(id));
    issue_identity(dir, &out, (&name, &grant), public_key, lifetime, domain)?;
    Ok(out)
}

/// Writes a DDS identity in `out`: a certificate for `public_key` with subject `name`, signed by
/// the fleet CA in `dir`, its permissions (granted to `grant`, the subject as a string) for
/// `domain`, and copies of the CA, the governance and the revocation list: everything a
/// participant needs but its private key.
fn issue_identity<K: openssl::pkey::HasPublic>(
    dir: &Path,
    out: &Path,
    (name, grant): (&X509Name, &str),
    public_key: &openssl::pkey::PKeyRef<K>,
    lifetime: Lifetime,
    domain: u16,
) -> anyhow::Result<()> {
    let (ca, ca_key) = fleet_ca(dir)?;
    std::fs::create_dir_all(out).with_context(|| format!("create {}", out.display()))?;
    let mut cert = builder(name, ca.subject_name(), public_key, lifetime)?;
    cert.append_extension(BasicConstraints::new().critical().build()?)?;
    cert.append_extension(
        KeyUsage::new()
            .critical()
            .digital_signature()
            .key_agreement()
            .build()?,
    )?;
    cert.sign(&ca_key, MessageDigest::sha256())?;
    let cert = cert.build();
    write(&out.join("cert.pem"), &cert.to_pem()?, false)?;
    let permissions = permissions_xml(grant, domain);
    write(
        &out.join("permissions.p7s"),
        &sign(&ca, &ca_key, &permissions)?,
        false,
    )?;
    let ca_pem = ca.to_pem()?;
    write(&out.join("identity_ca.cert.pem"), &ca_pem, false)?;
    write(&out.join("permissions_ca.cert.pem"), &ca_pem, false)?;
    write(
        &out.join("governance.p7s"),
        &fleet_file(dir, "governance.p7s")?,
        false,
    )?;
    // A fleet made before revocation lists gets its (empty) list now.
    if !dir.join(CRL_FILE).exists() {
        revocation::write_list(dir, &ca, &ca_key, &[])?;
    }
    revocation::copy_to(dir, out)
}

/// The fleet's DDS domain (its `domain` file).
fn fleet_domain(dir: &Path) -> anyhow::Result<u16> {
    String::from_utf8_lossy(&fleet_file(dir, "domain")?)
        .trim()
        .parse()
        .context("the fleet's domain file")
}

/// Issues the browser console's server certificate (docs/web.md), signed by the fleet CA, for
/// the names and addresses in `hosts`, in `DIR/web-HOST/` (`cert.pem`, `key.pem`): point
/// `[web] certificate` and `key` there. Browsers that trust the fleet's `ca.cert.pem` then
/// accept the page without a warning.
///
/// # Errors
/// `dir` holds no fleet, `hosts` is empty, the files exist, or OpenSSL fails.
pub fn web(dir: &Path, hosts: &[String], lifetime: Lifetime) -> anyhow::Result<PathBuf> {
    use openssl::x509::extension::ExtendedKeyUsage;
    let Some(first) = hosts.first() else {
        bail!("name at least one host (--host NAME or address)");
    };
    let (ca, ca_key) = fleet_ca(dir)?;
    let out = dir.join(format!("web-{first}"));
    if out.join("cert.pem").exists() {
        bail!("{} exists already", out.join("cert.pem").display());
    }
    std::fs::create_dir_all(&out).with_context(|| format!("create {}", out.display()))?;
    let name = subject(&fleet_of(&ca)?, first)?;
    let usage = ExtendedKeyUsage::new().server_auth().build()?;
    issue_tls(&out, (&ca, &ca_key), &name, hosts, usage, lifetime)?;
    Ok(out)
}

/// A TLS certificate for `subject` signed by the fleet's CA, with `hosts` (names or addresses)
/// as subject alternative names and `usage`, and a new key: `cert.pem` and `key.pem` in `out`.
fn issue_tls(
    out: &Path,
    (ca, ca_key): (&X509, &PKey<Private>),
    subject: &X509Name,
    hosts: &[String],
    usage: openssl::x509::X509Extension,
    lifetime: Lifetime,
) -> anyhow::Result<()> {
    use openssl::x509::extension::SubjectAlternativeName;
    let key = new_key()?;
    let mut cert = builder(subject, ca.subject_name(), &key, lifetime)?;
    if !hosts.is_empty() {
        let mut names = SubjectAlternativeName::new();
        for host in hosts {
            if host.parse::<std::net::IpAddr>().is_ok() {
                names.ip(host);
            } else {
                names.dns(host);
            }
        }
        let names = names.build(&cert.x509v3_context(Some(ca), None))?;
        cert.append_extension(names)?;
    }
    cert.append_extension(BasicConstraints::new().critical().build()?)?;
    cert.append_extension(KeyUsage::new().critical().digital_signature().build()?)?;
    cert.append_extension(usage)?;
    cert.sign(ca_key, MessageDigest::sha256())?;
    write(&out.join("cert.pem"), &cert.build().to_pem()?, false)?;
    write(&out.join("key.pem"), &key.private_key_to_pem_pkcs8()?, true)?;
    Ok(())
}

/// The files of a device directory (`[security] dir`), as rustdds reads them.
pub const DEVICE_FILES: [&str; 6] = [
    "identity_ca.cert.pem",
    "cert.pem",
    "key.pem",
    "permissions_ca.cert.pem",
    "governance.p7s",
    "permissions.p7s",
];

/// Checks a device directory before joining: every file is there, and the certificate is
/// device `id`'s (unless `any_id`, a test hook). Returns the fleet identity for pinning ids.
///
/// # Errors
/// A file is missing or unreadable, or the certificate is another device's.
pub fn check_device_dir(dir: &Path, id: DeviceId, any_id: bool) -> anyhow::Result<FleetIdentity> {
    let (cn, who) = (common_name(id), format!("device {id}"));
    check_identity(dir, (!any_id).then_some((cn.as_str(), who.as_str())))
}

/// [`check_device_dir`] for a directory whose certificate has the common name `expected`.
///
/// # Errors
/// As [`check_device_dir`].
fn check_identity_dir(dir: &Path, expected: &str) -> anyhow::Result<FleetIdentity> {
    check_identity(dir, Some((expected, expected)))
}

/// [`check_device_dir`]: the certificate's common name must be `expected.0` (`expected.1` says
/// whose it should be), if given.
fn check_identity(dir: &Path, expected: Option<(&str, &str)>) -> anyhow::Result<FleetIdentity> {
    for name in DEVICE_FILES {
        let path = dir.join(name);
        std::fs::metadata(&path)
            .with_context(|| format!("[security] {}: missing {name}", dir.display()))?;
    }
    let pem = std::fs::read(dir.join("cert.pem"))?;
    let cert = X509::from_pem(&pem).context("cert.pem is not a PEM certificate")?;
    let cn = (cert.subject_name().entries_by_nid(Nid::COMMONNAME).next())
        .map(|e| e.data().to_string())
        .transpose()?
        .unwrap_or_default();
    if let Some((expected, who)) = expected
        && cn != expected
    {
        bail!(
            "[security] {}: the certificate is {cn:?}'s, not {who}'s ({expected:?})",
            dir.display(),
        );
    }
    // A certificate signed for another request than this key's (`rove keys sign`).
    let key =
        PKey::private_key_from_pem(&std::fs::read(dir.join("key.pem"))?).with_context(|| {
            format!(
                "[security] {}: key.pem is not a PEM private key",
                dir.display()
            )
        })?;
    if !cert.public_key()?.public_eq(&key) {
        bail!(
            "[security] {}: cert.pem was not issued for key.pem (sign this device's own request)",
            dir.display()
        );
    }
    FleetIdentity::from_certificate(&pem)
}

/// Who may speak for which device id in a secured fleet; see the module docs.
#[derive(Debug)]
pub struct FleetIdentity {
    fleet: String,
    /// The expected GUID starts per id, computed once: [`FleetIdentity::speaks_for`] runs for
    /// every sample. Bounded: a flood of invented ids starts it afresh.
    starts: std::sync::Mutex<std::collections::HashMap<DeviceId, Starts>>,
}

/// The GUID starts of the certificates that speak for one id: its own, and a site proxy's at
/// each level (in [`Level::ALL`] order).
type Starts = [Option<[u8; 6]>; 4];

/// Most ids whose GUID start [`FleetIdentity`] remembers.
const MAX_CACHED_IDS: usize = 4096;

impl FleetIdentity {
    /// The fleet's name (the certificates' organisation).
    pub fn fleet(&self) -> &str {
        &self.fleet
    }

    /// The fleet a device's own certificate (PEM) belongs to.
    ///
    /// # Errors
    /// The certificate cannot be read or names no organisation.
    pub fn from_certificate(pem: &[u8]) -> anyhow::Result<FleetIdentity> {
        Ok(FleetIdentity {
            fleet: fleet_of(&X509::from_pem(pem)?)?,
            starts: Default::default(),
        })
    }

    /// The first six bytes of the GUID prefix a participant certified as device `id` has.
    ///
    /// # Errors
    /// OpenSSL fails to encode the subject.
    pub fn guid_start(&self, id: DeviceId) -> anyhow::Result<[u8; 6]> {
        guid_start_for(&*subject(&self.fleet, &common_name(id))?)
    }

    /// What `participant` (authenticated by DDS Security) is for device `id`: the device
    /// itself, another site's device shown by this site's bridge (a site proxy certificate,
    /// `rove keys site --proxies`), or neither.
    pub fn speaks_for(&self, id: DeviceId, participant: ParticipantId) -> Certified {
        let mut starts = crate::runtime::lock(&self.starts);
        if starts.len() >= MAX_CACHED_IDS && !starts.contains_key(&id) {
            starts.clear();
        }
        let expected = *starts.entry(id).or_insert_with(|| {
            let own = self.guid_start(id).ok();
            let proxy = |level| {
                site::proxy_subject(&self.fleet, id, level).and_then(|s| guid_start_for(&s))
            };
            let [remote, stationary, mobile] = Level::ALL.map(|l| proxy(l).ok());
            [own, remote, stationary, mobile]
        });
        let start = guid_start_of(participant);
        match expected.iter().position(|e| *e == Some(start)) {
            Some(0) => Certified::Device,
            Some(i) => Certified::Proxy(Level::ALL[i - 1]),
            None => Certified::No,
        }
    }
}

/// The first six bytes of the GUID prefix of a participant whose certificate has `subject`
/// (DDS Security §9.3.3).
fn guid_start_for(subject: &openssl::x509::X509NameRef) -> anyhow::Result<[u8; 6]> {
    let digest = hash(MessageDigest::sha256(), &subject.to_der()?)?;
    let mut first = [0u8; 8];
    first.copy_from_slice(&digest[..8]);
    let bits = (u64::from_be_bytes(first) >> 1) | (1 << 63);
    let mut start = [0u8; 6];
    start.copy_from_slice(&bits.to_be_bytes()[..6]);
    Ok(start)
}

/// The first six bytes of `participant`'s GUID prefix (which `ParticipantId` holds in its low
/// 12 bytes, `dds::participant_id`).
fn guid_start_of(participant: ParticipantId) -> [u8; 6] {
    let bytes = participant.0.to_be_bytes();
    let mut start = [0u8; 6];
    start.copy_from_slice(&bytes[4..10]);
    start
}

/// A file of the fleet in `dir`.
fn fleet_file(dir: &Path, name: &str) -> anyhow::Result<Vec<u8>> {
    let path = dir.join(name);
    std::fs::read(&path).with_context(|| format!("read {} (run `rove keys init`)", path.display()))
}

/// The fleet CA in `dir`: its certificate and key.
fn fleet_ca(dir: &Path) -> anyhow::Result<(X509, PKey<Private>)> {
    let ca = X509::from_pem(&fleet_file(dir, "ca.cert.pem")?)?;
    let key = PKey::private_key_from_pem(&fleet_file(dir, "ca.key.pem")?)?;
    Ok((ca, key))
}

fn new_key() -> anyhow::Result<PKey<Private>> {
    let group = EcGroup::from_curve_name(Nid::X9_62_PRIME256V1)?;
    Ok(PKey::from_ec_key(EcKey::generate(&group)?)?)
}

fn subject(fleet: &str, common_name: &str) -> anyhow::Result<X509Name> {
    let mut name = X509NameBuilder::new()?;
    name.append_entry_by_nid(Nid::ORGANIZATIONNAME, fleet)?;
    name.append_entry_by_nid(Nid::COMMONNAME, common_name)?;
    Ok(name.build())
}

fn fleet_of(cert: &X509) -> anyhow::Result<String> {
    let entry = (cert
        .subject_name()
        .entries_by_nid(Nid::ORGANIZATIONNAME)
        .next())
    .ok_or_else(|| anyhow!("the certificate names no organisation (O=): not a rove fleet's"))?;
    Ok(entry.data().to_string()?)
}

fn builder<K: openssl::pkey::HasPublic>(
    subject: &openssl::x509::X509NameRef,
    issuer: &openssl::x509::X509NameRef,
    key: &openssl::pkey::PKeyRef<K>,
    lifetime: Lifetime,
) -> anyhow::Result<X509Builder> {
    let mut cert = X509Builder::new()?;
    cert.set_version(2)?;
    let mut serial = BigNum::new()?;
    serial.rand(127, MsbOption::MAYBE_ZERO, false)?;
    let serial = serial.to_asn1_integer()?;
    cert.set_serial_number(&serial)?;
    cert.set_subject_name(subject)?;
    cert.set_issuer_name(issuer)?;
    cert.set_pubkey(key)?;
    let (from, until) = lifetime.period()?;
    cert.set_not_before(&from)?;
    cert.set_not_after(&until)?;
    Ok(cert)
}

/// `document` S/MIME clear-signed (as `openssl smime -sign -text`) by `cert`.
fn sign(cert: &X509, key: &PKey<Private>, document: &str) -> anyhow::Result<Vec<u8>> {
    let flags = Pkcs7Flags::DETACHED | Pkcs7Flags::TEXT;
    let certs = Stack::new()?;
    let signed = Pkcs7::sign(cert, key, &certs, document.as_bytes(), flags)?;
    Ok(signed.to_smime(document.as_bytes(), flags)?)
}

fn write(path: &Path, contents: &[u8], secret: bool) -> anyhow::Result<()> {
    crate::runtime::create_file(path, contents, if secret { 0o600 } else { 0o644 })
}

fn governance_xml(domain: u16) -> String {
    format!(
        r#"<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/omg_shared_ca_governance.xsd">
    <domain_access_rules>
        <domain_rule>
            <domains>
                <id>{domain}</id>
            </domains>
            <allow_unauthenticated_participants>false</allow_unauthenticated_participants>
            <enable_join_access_control>true</enable_join_access_control>
            <discovery_protection_kind>NONE</discovery_protection_kind>
            <liveliness_protection_kind>NONE</liveliness_protection_kind>
            <rtps_protection_kind>ENCRYPT_WITH_ORIGIN_AUTHENTICATION</rtps_protection_kind>
            <topic_access_rules>
                <topic_rule>
                    <topic_expression>*</topic_expression>
                    <enable_discovery_protection>false</enable_discovery_protection>
                    <enable_liveliness_protection>false</enable_liveliness_protection>
                    <enable_read_access_control>true</enable_read_access_control>
                    <enable_write_access_control>true</enable_write_access_control>
                    <metadata_protection_kind>NONE</metadata_protection_kind>
                    <data_protection_kind>NONE</data_protection_kind>
                </topic_rule>
            </topic_access_rules>
        </domain_rule>
    </domain_access_rules>
</dds>
"#
    )
}

/// The permissions of the participant whose subject is `grant` (as `CN=…,O=…`): rove's topics
/// in `domain`, both ways.
fn permissions_xml(grant: &str, domain: u16) -> String {
    let topics: String = TOPICS
        .iter()
        .map(|t| format!("                        <topic>{t}</topic>\n"))
        .collect();
    let not_before = "2020-01-01T00:00:00";
    let not_after = "9999-01-01T00:00:00";
    format!(
        r#"<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-Security/20170901/omg_shared_ca_permissions.xsd">
    <permissions>
        <grant name="{grant}">
            <subject_name>{grant}</subject_name>
            <validity>
                <not_before>{not_before}</not_before>
                <not_after>{not_after}</not_after>
            </validity>
            <allow_rule>
                <domains>
                    <id>{domain}</id>
                </domains>
                <publish>
                    <topics>
{topics}                    </topics>
                </publish>
                <subscribe>
                    <topics>
{topics}                    </topics>
                </subscribe>
            </allow_rule>
            <default>DENY</default>
        </grant>
    </permissions>
</dds>
"#
    )
}

#[cfg(test)]
mod tests;
