//! Keys born on their device (issue 44): `rove keys request` makes a device's private key and a
//! certificate request where the key is to stay; `rove keys sign` at the fleet CA turns the
//! request into the device's certificate and permissions without ever seeing the key.
//!
//! The request is a PKCS#10 CSR (`request.csr.pem`), subject `CN=rove-ID`, signed by the new
//! key: the CA checks that signature (the requester holds the key), that the key is EC P-256
//! (what rustdds's builtin plugins take) and that the id is the one the person at the CA
//! confirms with `--id`. The certificate's subject is the CA's own (`O=<fleet>, CN=rove-ID`),
//! whatever else the request says.

use super::{DEVICE_FILES, Lifetime, bail, issue_device, new_key, write};
use anyhow::Context;
use openssl::hash::MessageDigest;
use openssl::nid::Nid;
use openssl::x509::{X509NameBuilder, X509Req, X509ReqBuilder};
use rove_core::msg::DeviceId;
use std::path::{Path, PathBuf};

/// The certificate request's file name, beside the key on the device.
pub const REQUEST_FILE: &str = "request.csr.pem";

/// On the device: a new private key (`DIR/key.pem`, mode 0600; `DIR` created mode 0700) and
/// the certificate request for device `id` (`DIR/request.csr.pem`), to take to the fleet CA.
/// Returns the request's path.
///
/// # Errors
/// `DIR` holds a key already (a device's key is made once), or a file cannot be written.
pub fn request(dir: &Path, id: DeviceId) -> anyhow::Result<PathBuf> {
    use std::os::unix::fs::DirBuilderExt;
    if id <= 0 {
        bail!("device id {id}: must be positive");
    }
    if dir.join("key.pem").exists() {
        bail!(
            "{} holds a private key already: a device's key is made once (remove it to start \
             over, then have the new request signed with `rove keys sign --renew`)",
            dir.display()
        );
    }
    std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(dir)
        .with_context(|| format!("create {}", dir.display()))?;
    let key = new_key()?;
    let mut name = X509NameBuilder::new()?;
    name.append_entry_by_nid(Nid::COMMONNAME, &super::common_name(id))?;
    let mut req = X509ReqBuilder::new()?;
    req.set_subject_name(&name.build())?;
    req.set_pubkey(&key)?;
    req.sign(&key, MessageDigest::sha256())?;
    write(&dir.join("key.pem"), &key.private_key_to_pem_pkcs8()?, true)?;
    let path = dir.join(REQUEST_FILE);
    write(&path, &req.build().to_pem()?, false)?;
    Ok(path)
}

/// At the fleet CA: device `id`'s certificate for the key in the request `request` (PEM), and
/// its permissions, in `FLEET/ID/` with the CA, the governance and the revocation list, and no
/// private key; returns that directory. Its files go to the device, beside its key.
///
/// # Errors
/// `dir` holds no fleet, the request does not verify, names another id or carries another kind
/// of key, the device exists (and not `renew`), or a file cannot be read or written.
pub fn sign_request(
    dir: &Path,
    request: &[u8],
    id: DeviceId,
    lifetime: Lifetime,
    renew: bool,
) -> anyhow::Result<PathBuf> {
    let req = X509Req::from_pem(request).context("the request is not a PEM certificate request")?;
    let key = req.public_key().context("the request's key")?;
    if !req.verify(&key).unwrap_or(false) {
        bail!("the request's signature does not verify: it was not made with its key");
    }
    let curve = (key.ec_key().ok()).and_then(|k| k.group().curve_name());
    if curve != Some(Nid::X9_62_PRIME256V1) {
        bail!("the request's key is not EC P-256 (make it with `rove keys request`)");
    }
    let cn = (req.subject_name().entries_by_nid(Nid::COMMONNAME).next())
        .map(|e| e.data().to_string())
        .transpose()?
        .unwrap_or_default();
    if cn != super::common_name(id) {
        bail!(
            "the request is for {cn:?}, not device {id} ({:?}): check the id with the device",
            super::common_name(id)
        );
    }
    // A renewed device keeps no key here (there never was one, or `rove keys add` made it).
    let replaced: Vec<&str> = DEVICE_FILES.to_vec();
    let out = issue_device(dir, id, &key, lifetime, renew, &replaced)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::super::{check_device_dir, init};
    use super::*;

    #[test]
    fn a_request_made_on_the_device_is_signed_without_its_key() {
        let tmp = tempfile::tempdir().expect("a temporary directory");
        let root = tmp.path().to_path_buf();
        let (fleet, device) = (root.join("fleet"), root.join("device"));
        init(&fleet, "test fleet", 0).expect("init");
        let req = request(&device, 100).expect("request");
        let mode = std::os::unix::fs::PermissionsExt::mode(
            &std::fs::metadata(device.join("key.pem"))
                .expect("key")
                .permissions(),
        );
        assert_eq!(mode & 0o777, 0o600);
        assert!(request(&device, 100).is_err(), "a key is made once");
        let pem = std::fs::read(&req).expect("request");
        let out = sign_request(&fleet, &pem, 100, Lifetime::DEVICE, false).expect("sign");
        assert!(!out.join("key.pem").exists(), "the CA never holds the key");
        // The device's directory: its own key, the CA's files beside it.
        for name in DEVICE_FILES.iter().filter(|n| **n != "key.pem") {
            std::fs::copy(out.join(name), device.join(name)).expect("copy");
        }
        check_device_dir(&device, 100, false).expect("a complete device directory");
        // The certificate holds the device's key.
        let cert = openssl::x509::X509::from_pem(
            &std::fs::read(device.join("cert.pem")).expect("test step"),
        )
        .expect("cert");
        let key = openssl::pkey::PKey::private_key_from_pem(
            &std::fs::read(device.join("key.pem")).expect("test step"),
        )
        .expect("key");
        assert!(cert.public_key().expect("test step").public_eq(&key));
        // Signed twice only with --renew.
        assert!(sign_request(&fleet, &pem, 100, Lifetime::DEVICE, false).is_err());
        sign_request(&fleet, &pem, 100, Lifetime::DEVICE, true).expect("renew");
    }

    #[test]
    fn a_request_for_another_id_or_tampered_with_is_refused() {
        let tmp = tempfile::tempdir().expect("a temporary directory");
        let root = tmp.path().to_path_buf();
        let fleet = root.join("fleet");
        init(&fleet, "test fleet", 0).expect("init");
        let req =
            std::fs::read(request(&root.join("d"), 100).expect("request")).expect("test step");
        let e = sign_request(&fleet, &req, 101, Lifetime::DEVICE, false).expect_err("an error");
        assert!(e.to_string().contains("not device 101"), "{e}");
        // The request's body changed after it was signed (its subject now says 101).
        let mut tampered = X509Req::from_pem(&req).expect("test step");
        let mut name = X509NameBuilder::new().expect("test step");
        name.append_entry_by_nid(Nid::COMMONNAME, "rove-101")
            .expect("test step");
        let mut other = X509ReqBuilder::new().expect("test step");
        other.set_subject_name(&name.build()).expect("test step");
        other
            .set_pubkey(&tampered.public_key().expect("test step"))
            .expect("test step");
        // Signed by another key than the one it carries.
        let stranger = new_key().expect("test step");
        other
            .sign(&stranger, MessageDigest::sha256())
            .expect("test step");
        tampered = other.build();
        let e = sign_request(
            &fleet,
            &tampered.to_pem().expect("test step"),
            101,
            Lifetime::DEVICE,
            false,
        )
        .expect_err("an error");
        assert!(e.to_string().contains("does not verify"), "{e}");
        assert!(sign_request(&fleet, b"not a request", 100, Lifetime::DEVICE, false).is_err());
    }
}
