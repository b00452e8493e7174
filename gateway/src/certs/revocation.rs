//! The fleet's certificate revocation list, `crl.pem`: signed by the fleet CA, kept in the
//! fleet directory and copied into every device directory beside the governance (distributed
//! the same way: copy the device directories, or just their `crl.pem`). Every participant
//! refuses a peer the list names when they authenticate, and reads the list again when its file
//! changes (ROVE-PATCH.md §14); a device the list names does not start.

use super::{fleet_ca, fleet_file, write};
use anyhow::{Context, bail};
use openssl::asn1::{Asn1Object, Asn1OctetString, Asn1Time};
use openssl::bn::BigNumContext;
use openssl::ec::PointConversionForm;
use openssl::hash::{MessageDigest, hash};
use openssl::nid::Nid;
use openssl::pkey::{PKey, Private};
use openssl::x509::{CrlStatus, X509, X509Crl, X509CrlBuilder, X509Extension, X509RevokedBuilder};
use rove_core::msg::DeviceId;
use std::path::{Path, PathBuf};

/// The list's file name, in the fleet directory and in each device directory.
pub const CRL_FILE: &str = "crl.pem";

/// Writes the fleet's list: what it revoked before, and `also` (certificates to revoke now).
/// Returns how many certificates it names.
pub(super) fn write_list(
    dir: &Path,
    ca: &X509,
    key: &PKey<Private>,
    also: &[X509],
) -> anyhow::Result<usize> {
    let mut builder = X509CrlBuilder::new()?;
    builder.set_issuer_name(ca.subject_name())?;
    let (from, until) = super::Lifetime::CA.period()?;
    builder.set_last_update(&from)?;
    builder.set_next_update(&until)?;
    let mut count = 0;
    if let Some(old) = read_list(dir)?
        && let Some(revoked) = old.get_revoked()
    {
        for entry in revoked {
            builder.add_revoked(entry.to_owned()?)?;
            count += 1;
        }
    }
    for cert in also {
        let mut entry = X509RevokedBuilder::new()?;
        entry.set_serial_number(cert.serial_number())?;
        let now = Asn1Time::days_from_now(0)?;
        entry.set_revocation_date(&now)?;
        builder.add_revoked(entry.build())?;
        count += 1;
    }
    builder.sort()?;
    // OpenSSL's builder wants the two extensions RFC 5280 asks of a CRL.
    builder.append_extension(extension(
        Nid::AUTHORITY_KEY_IDENTIFIER,
        &authority_key_id(ca)?,
    )?)?;
    builder.append_extension(extension(Nid::CRL_NUMBER, &crl_number()?)?)?;
    builder.sign(key, MessageDigest::sha256())?;
    let pem = builder.build()?.to_pem()?;
    let path = dir.join(CRL_FILE);
    let _ = std::fs::remove_file(&path);
    write(&path, &pem, false)?;
    Ok(count)
}

/// A non-critical extension with DER contents `der`.
fn extension(nid: Nid, der: &[u8]) -> anyhow::Result<X509Extension> {
    let oid = Asn1Object::from_str(nid.short_name()?)?;
    let contents = Asn1OctetString::new_from_bytes(der)?;
    Ok(X509Extension::new_from_der(&oid, false, &contents)?)
}

/// AuthorityKeyIdentifier: the CA's key id (its SubjectKeyIdentifier, or the SHA-1 of its public
/// key's point, RFC 5280's method 1: `rove keys init` writes no SubjectKeyIdentifier).
fn authority_key_id(ca: &X509) -> anyhow::Result<Vec<u8>> {
    let id = match ca.subject_key_id() {
        Some(id) => id.as_slice().to_vec(),
        None => {
            let key = ca.public_key()?.ec_key()?;
            let mut ctx = BigNumContext::new()?;
            let point = key.public_key().to_bytes(
                key.group(),
                PointConversionForm::UNCOMPRESSED,
                &mut ctx,
            )?;
            hash(MessageDigest::sha1(), &point)?.to_vec()
        }
    };
    let len = u8::try_from(id.len()).context("a key id longer than 127 bytes")?;
    // SEQUENCE { [0] keyIdentifier }
    let mut der = vec![0x30, len + 2, 0x80, len];
    der.extend_from_slice(&id);
    Ok(der)
}

/// CRLNumber: increasing with each list, so the time it is written, in seconds (DER INTEGER).
fn crl_number() -> anyhow::Result<Vec<u8>> {
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .context("the system clock is before 1970")?
        .as_secs();
    let bytes = now.to_be_bytes();
    let first = bytes
        .iter()
        .position(|&b| b != 0)
        .unwrap_or(bytes.len() - 1);
    let mut value = bytes[first..].to_vec();
    if value[0] & 0x80 != 0 {
        value.insert(0, 0);
    }
    let mut der = vec![0x02, value.len() as u8];
    der.extend_from_slice(&value);
    Ok(der)
}

/// The fleet's list, if it has one.
pub(super) fn read_list(dir: &Path) -> anyhow::Result<Option<X509Crl>> {
    let path = dir.join(CRL_FILE);
    if !path.exists() {
        return Ok(None);
    }
    let pem = std::fs::read(&path).with_context(|| format!("read {}", path.display()))?;
    let crl = X509Crl::from_pem(&pem).with_context(|| format!("{}: not a CRL", path.display()))?;
    Ok(Some(crl))
}

/// Whether the fleet's list in `dir` names the certificate in `pem`.
fn is_revoked(dir: &Path, pem: &[u8]) -> anyhow::Result<bool> {
    names(read_list(dir)?.as_ref(), pem)
}

/// Whether `list` (none: nothing is revoked) names the certificate in `pem`.
pub(super) fn names(list: Option<&X509Crl>, pem: &[u8]) -> anyhow::Result<bool> {
    let Some(crl) = list else {
        return Ok(false);
    };
    let cert = X509::from_pem(pem)?;
    Ok(!matches!(crl.get_by_cert(&cert), CrlStatus::NotRevoked))
}

/// Copies the fleet's list into the device directory `out`.
pub(super) fn copy_to(dir: &Path, out: &Path) -> anyhow::Result<()> {
    copy_fleet_file(dir, out, CRL_FILE)
}

/// Copies the fleet's file `name` into `out`, replacing the copy there.
fn copy_fleet_file(dir: &Path, out: &Path, name: &str) -> anyhow::Result<()> {
    let target = out.join(name);
    let _ = std::fs::remove_file(&target);
    write(&target, &fleet_file(dir, name)?, false)
}

/// A secured site's DDS identity directories in `site` (`DIR/site-NAME`): the bridge's own
/// (`dds/`) and each proxy's (`proxies/ID/`), whether issued or not.
fn site_identities(site: &Path) -> impl Iterator<Item = PathBuf> {
    let proxies = std::fs::read_dir(site.join("proxies"));
    std::iter::once(site.join("dds"))
        .chain((proxies.into_iter().flatten().flatten()).map(|e| e.path()))
}

/// What `rove keys revoke` did.
#[derive(Debug)]
pub struct Revoked {
    /// Certificates the list names now.
    pub listed: usize,
    /// The device directories the new list was copied into.
    pub copied: Vec<PathBuf>,
}

/// Revokes device `id`'s certificate: the fleet's list names it, and every device directory in
/// the fleet gets the new list.
///
/// # Errors
/// `dir` holds no fleet or no such device, its certificate is revoked already, or a file
/// cannot be read or written.
pub fn revoke(dir: &Path, id: DeviceId) -> anyhow::Result<Revoked> {
    let (ca, key) = fleet_ca(dir)?;
    let path = dir.join(id.to_string()).join("cert.pem");
    let pem = std::fs::read(&path).with_context(|| {
        format!(
            "device {id}: read {} (is it in this fleet?)",
            path.display()
        )
    })?;
    if is_revoked(dir, &pem)? {
        bail!("device {id}'s certificate is revoked already");
    }
    let cert = X509::from_pem(&pem)?;
    let listed = write_list(dir, &ca, &key, std::slice::from_ref(&cert))?;
    let copied = distribute(dir)?;
    Ok(Revoked { listed, copied })
}

/// Copies the fleet's list into every identity directory of the fleet (each device's, each
/// secured site's `dds/` and `proxies/ID/`), and its revoked site names into every site
/// directory (beside the link's `ca.cert.pem`); returns the directories written.
fn distribute(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut copied = Vec::new();
    for issued in super::list(dir)? {
        let out = dir.join(issued.id.to_string());
        copy_to(dir, &out)?;
        copied.push(out);
    }
    let sites = std::fs::read_dir(dir).with_context(|| format!("read {}", dir.display()))?;
    for site in sites.flatten() {
        let is_site = site.file_name().to_string_lossy().starts_with("site-");
        if !is_site || !site.path().join("ca.cert.pem").exists() {
            continue;
        }
        for out in site_identities(&site.path()).filter(|d| d.join("cert.pem").exists()) {
            copy_to(dir, &out)?;
            copied.push(out);
        }
        if dir.join(REVOKED_SITES_FILE).exists() {
            copy_fleet_file(dir, &site.path(), REVOKED_SITES_FILE)?;
            copied.push(site.path());
        }
    }
    Ok(copied)
}

/// The file naming the fleet's revoked sites, one per line, S/MIME signed by the fleet CA: in
/// the fleet directory and, from `rove keys revoke --site`, in every site directory beside
/// `ca.cert.pem`. A bridge refuses a site it names on the link (docs/remote.md).
pub const REVOKED_SITES_FILE: &str = "revoked-sites.p7s";

/// Revokes site `name`: the fleet's list names its link certificate and, for a secured site,
/// its DDS identities (so every device drops its bridge's participants, ROVE-PATCH.md §14);
/// the signed list of revoked sites names it (so every bridge refuses it on the link). Both go
/// to every directory of the fleet.
///
/// # Errors
/// `dir` holds no fleet or no such site, the site is revoked already, or a file cannot be
/// read or written.
pub fn revoke_site(dir: &Path, name: &rove_core::site::SiteName) -> anyhow::Result<Revoked> {
    let (ca, key) = fleet_ca(dir)?;
    let site = dir.join(format!("site-{name}"));
    let mut names = match dir.join(REVOKED_SITES_FILE).exists() {
        true => revoked_sites(&dir.join("ca.cert.pem"), &dir.join(REVOKED_SITES_FILE))?,
        false => Default::default(),
    };
    if !names.insert(name.to_string()) {
        bail!("site {name} is revoked already");
    }
    let files = std::iter::once(site.join("cert.pem"))
        .chain(site_identities(&site).map(|d| d.join("cert.pem")));
    let mut certs = Vec::new();
    for file in files.filter(|f| f.exists()) {
        let pem = std::fs::read(&file).with_context(|| format!("read {}", file.display()))?;
        if !is_revoked(dir, &pem)? {
            certs.push(X509::from_pem(&pem)?);
        }
    }
    if certs.is_empty() && !site.join("cert.pem").exists() {
        bail!("site {name}: no {} (is it in this fleet?)", site.display());
    }
    let listed = write_list(dir, &ca, &key, &certs)?;
    let text: String = names.iter().map(|n| format!("{n}\n")).collect();
    let path = dir.join(REVOKED_SITES_FILE);
    let _ = std::fs::remove_file(&path);
    write(&path, &super::sign(&ca, &key, &text)?, false)?;
    let copied = distribute(dir)?;
    Ok(Revoked { listed, copied })
}

/// The site names in a [`REVOKED_SITES_FILE`] at `file`, checked to be signed by the CA
/// certificate at `ca`.
///
/// # Errors
/// A file cannot be read, or the list is not signed by that CA.
pub fn revoked_sites(ca: &Path, file: &Path) -> anyhow::Result<std::collections::BTreeSet<String>> {
    use openssl::pkcs7::{Pkcs7, Pkcs7Flags};
    use openssl::stack::Stack;
    use openssl::x509::store::X509StoreBuilder;
    let ca = X509::from_pem(&std::fs::read(ca).with_context(|| format!("read {}", ca.display()))?)?;
    let bytes = std::fs::read(file).with_context(|| format!("read {}", file.display()))?;
    let refuse = || format!("{}: not signed by the fleet CA", file.display());
    let (signed, content) = Pkcs7::from_smime(&bytes).with_context(refuse)?;
    // The CA signs with a certificate-signing key: check the signature with the CA itself
    // (NOVERIFY skips the chain's purpose check), then that the signer is the CA.
    let mut store = X509StoreBuilder::new()?;
    store.add_cert(ca.clone())?;
    let mut out = Vec::new();
    let flags = Pkcs7Flags::TEXT | Pkcs7Flags::NOVERIFY;
    let none: Stack<X509> = Stack::new()?;
    (signed.verify(
        &none,
        &store.build(),
        content.as_deref(),
        Some(&mut out),
        flags,
    ))
    .with_context(refuse)?;
    let signers = signed
        .signers(&none, Pkcs7Flags::empty())
        .with_context(refuse)?;
    let by_ca = signers.iter().all(|s| s.to_der().ok() == ca.to_der().ok()) && signers.len() == 1;
    anyhow::ensure!(by_ca, refuse());
    Ok((String::from_utf8_lossy(&out).lines())
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .map(str::to_string)
        .collect())
}
