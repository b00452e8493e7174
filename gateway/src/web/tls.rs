//! The browser console's TLS identity: a certificate and key loaded from `[web]`, or a
//! self-signed one made here (and written to the configured files when they do not exist yet,
//! so a browser that accepted it once keeps trusting it across restarts).

use crate::runtime::create_file;
use anyhow::Context;
use rustls::pki_types::pem::PemObject;
use rustls::pki_types::{CertificateDer, PrivateKeyDer};
use std::sync::Arc;

/// A server identity ready for rustls, and what to tell the person about it.
#[derive(Debug)]
pub struct Identity {
    /// The server configuration (HTTP/1.1 only).
    pub config: Arc<rustls::ServerConfig>,
    /// SHA-256 of the leaf certificate, as `AB:CD:…`: what a browser shows to check it.
    pub fingerprint: String,
    /// Where it came from, for the start-up line.
    pub origin: String,
}

/// Names a self-signed certificate is made for: loopback, this host's name, and the listen
/// address when it is a specific one.
fn names(listen: std::net::SocketAddr) -> Vec<String> {
    let mut names = vec!["localhost".to_string(), "127.0.0.1".to_string()];
    if let Ok(host) = std::fs::read_to_string("/etc/hostname") {
        let host = host.trim();
        if !host.is_empty() {
            names.push(host.to_string());
            names.push(format!("{host}.local"));
        }
    }
    if !listen.ip().is_unspecified() {
        names.push(listen.ip().to_string());
    }
    names.dedup();
    names
}

/// Loads `[web] certificate` and `key`, or makes a self-signed pair (written to them if both are
/// missing, kept in memory if none is configured).
///
/// # Errors
/// A file cannot be read, parsed or written, or only one of the two exists.
pub fn identity(
    files: Option<&(std::path::PathBuf, std::path::PathBuf)>,
    listen: std::net::SocketAddr,
) -> anyhow::Result<Identity> {
    let (chain, key, origin) = match files {
        Some((cert, key)) => match (cert.exists(), key.exists()) {
            (true, true) => {
                let chain = CertificateDer::pem_file_iter(cert)
                    .and_then(Iterator::collect::<Result<Vec<_>, _>>)
                    .with_context(|| format!("[web] certificate {}", cert.display()))?;
                let pem = PrivateKeyDer::from_pem_file(key)
                    .with_context(|| format!("[web] key {}", key.display()))?;
                (chain, pem, format!("loaded from {}", cert.display()))
            }
            (false, false) => {
                let (chain, pem, cert_pem, key_pem) = self_signed(listen)?;
                create_file(cert, cert_pem.as_bytes(), 0o644).context("[web] certificate")?;
                create_file(key, key_pem.as_bytes(), 0o600).context("[web] key")?;
                (
                    chain,
                    pem,
                    format!("self-signed, written to {}", cert.display()),
                )
            }
            _ => anyhow::bail!(
                "[web]: only one of {} and {} exists; remove it to make a new pair, or supply both",
                cert.display(),
                key.display()
            ),
        },
        None => {
            let (chain, pem, _, _) = self_signed(listen)?;
            let origin = "self-signed in memory (a new one at every start; set [web] \
                          certificate and key to keep it)";
            (chain, pem, origin.to_string())
        }
    };
    let leaf = chain
        .first()
        .context("[web] certificate: the file has no certificate")?;
    let fingerprint = ring::digest::digest(&ring::digest::SHA256, leaf.as_ref())
        .as_ref()
        .iter()
        .map(|b| format!("{b:02X}"))
        .collect::<Vec<_>>()
        .join(":");
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let mut config = rustls::ServerConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .context("TLS protocol versions")?
        .with_no_client_auth()
        .with_single_cert(chain, key)
        .context("[web] certificate and key do not match")?;
    config.alpn_protocols = vec![b"http/1.1".to_vec()];
    Ok(Identity {
        config: Arc::new(config),
        fingerprint,
        origin,
    })
}

type Made = (
    Vec<CertificateDer<'static>>,
    PrivateKeyDer<'static>,
    String,
    String,
);

fn self_signed(listen: std::net::SocketAddr) -> anyhow::Result<Made> {
    let made =
        rcgen::generate_simple_self_signed(names(listen)).context("self-signed certificate")?;
    let key_der = made.signing_key.serialize_der();
    let key = PrivateKeyDer::try_from(key_der).map_err(|e| anyhow::anyhow!("key: {e}"))?;
    let cert_pem = made.cert.pem();
    let key_pem = made.signing_key.serialize_pem();
    Ok((vec![made.cert.der().clone()], key, cert_pem, key_pem))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_made_pair_is_written_once_then_loaded_with_the_same_fingerprint() {
        let dir = tempfile::tempdir().expect("tempdir");
        let files = (dir.path().join("web.crt"), dir.path().join("web.key"));
        let listen = "127.0.0.1:8443".parse().expect("addr");
        let made = identity(Some(&files), listen).expect("made");
        assert!(made.origin.starts_with("self-signed, written"));
        let mode = std::fs::metadata(&files.1).expect("key").permissions();
        assert_eq!(
            std::os::unix::fs::PermissionsExt::mode(&mode) & 0o777,
            0o600
        );
        let loaded = identity(Some(&files), listen).expect("loaded");
        assert!(loaded.origin.starts_with("loaded"));
        assert_eq!(made.fingerprint, loaded.fingerprint);
        assert_eq!(made.fingerprint.len(), 32 * 3 - 1);
    }

    #[test]
    fn one_file_without_the_other_is_an_error_that_names_them() {
        let dir = tempfile::tempdir().expect("tempdir");
        let files = (dir.path().join("web.crt"), dir.path().join("web.key"));
        std::fs::write(&files.0, "not a certificate").expect("write");
        let listen = "0.0.0.0:8443".parse().expect("addr");
        let err = identity(Some(&files), listen).expect_err("refused");
        assert!(err.to_string().contains("web.key"), "{err}");
    }
}
