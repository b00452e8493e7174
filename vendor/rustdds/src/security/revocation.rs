// rove patch (revocation list, ROVE-PATCH.md §14): the identity CA's certificate revocation
// list. Upstream checks none.
//
// The list is a PEM X.509 CRL (`openssl crl`), signed by the identity CA; rove's
// `rove keys revoke` writes it and copies it next to every device's governance. It is read at
// start (a list that does not verify against the CA is refused: the participant does not
// start) and read again whenever its file changes, before each check; a changed list that no
// longer reads or verifies is logged and the previous one kept.

use std::{path::PathBuf, sync::Mutex, time::SystemTime};

use openssl::x509::{CrlStatus, X509Crl, X509};

use crate::{
  create_security_error_and_log,
  security::{
    certificate::Certificate,
    config::read_uri,
    types::{SecurityError, SecurityResult},
  },
};

/// The property naming the list (as Cyclone DDS and OpenDDS name it).
pub(crate) const QOS_CRL_PROPERTY_NAME: &str = "dds.sec.auth.crl";

pub(crate) struct RevocationList {
  uri: String,
  /// The file, for `file:` URIs: its changes are noticed.
  path: Option<PathBuf>,
  ca: X509,
  state: Mutex<State>,
}

struct State {
  modified: Option<SystemTime>,
  crl: X509Crl,
  /// A new list was read since [`RevocationList::take_changed`] last said so. Peers were
  /// checked against the list in use when they authenticated, so only a new list can revoke
  /// one that is already matched.
  changed: bool,
}

impl RevocationList {
  /// Reads the list at `uri` and checks that `ca` issued and signed it.
  pub(crate) fn load(uri: &str, ca: &Certificate) -> SecurityResult<RevocationList> {
    let ca = X509::from_pem(ca.to_pem().as_bytes())
      .map_err(|e| create_security_error_and_log!("revocation list: the identity CA: {e}"))?;
    let path = uri.strip_prefix("file:").map(PathBuf::from);
    let modified = path.as_ref().and_then(|p| modified(p));
    let crl = read(uri, &ca)?;
    Ok(RevocationList {
      uri: uri.to_string(),
      path,
      ca,
      state: Mutex::new(State {
        modified,
        crl,
        changed: false,
      }),
    })
  }

  /// How many certificates the list revokes now.
  pub(crate) fn len(&self) -> usize {
    let state = self.state.lock().unwrap_or_else(|e| e.into_inner());
    state.crl.get_revoked().map_or(0, |r| r.len())
  }

  /// Reads the list again if its file changed since it was last read.
  pub(crate) fn refresh(&self) {
    let Some(path) = &self.path else {
      return;
    };
    let now = modified(path);
    let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
    if now == state.modified {
      return;
    }
    state.modified = now;
    match read(&self.uri, &self.ca) {
      Ok(crl) => {
        let n = crl.get_revoked().map_or(0, |r| r.len());
        log::info!("revocation list {} read again: {n} certificates revoked", self.uri);
        state.crl = crl;
        state.changed = true;
      }
      Err(e) => log::error!(
        "revocation list {} changed but cannot be used, the previous one is kept: {}",
        self.uri,
        e.msg
      ),
    }
  }

  /// Whether a new list was read since the last call (whoever refreshed it: a handshake or
  /// the periodic check of matched peers).
  pub(crate) fn take_changed(&self) -> bool {
    let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
    std::mem::take(&mut state.changed)
  }

  /// `Err` if the list revokes `cert`: the error names the subject and the date.
  pub(crate) fn check(&self, cert: &Certificate) -> SecurityResult<()> {
    let x509 = X509::from_pem(cert.to_pem().as_bytes())
      .map_err(|e| create_security_error_and_log!("revocation check: {e}"))?;
    let state = self.state.lock().unwrap_or_else(|e| e.into_inner());
    match state.crl.get_by_cert(&x509) {
      CrlStatus::NotRevoked => Ok(()),
      CrlStatus::Revoked(entry) | CrlStatus::RemoveFromCrl(entry) => {
        Err(crate::security::types::security_error(&format!(
          "certificate of {} is revoked (since {})",
          cert.subject_name(),
          entry.revocation_date()
        )))
      }
    }
  }
}

fn modified(path: &std::path::Path) -> Option<SystemTime> {
  std::fs::metadata(path).and_then(|m| m.modified()).ok()
}

/// Reads the list at `uri`: it must be `ca`'s and verify against `ca`'s key.
fn read(uri: &str, ca: &X509) -> SecurityResult<X509Crl> {
  let pem = read_uri(uri)
    .map_err(|e| create_security_error_and_log!("revocation list {uri}: cannot read: {e:?}"))?;
  let crl = X509Crl::from_pem(&pem)
    .map_err(|e| create_security_error_and_log!("revocation list {uri}: not a PEM CRL: {e}"))?;
  let issuer = |n: &openssl::x509::X509NameRef| n.to_der().unwrap_or_default();
  if issuer(crl.issuer_name()) != issuer(ca.subject_name()) {
    return Err(create_security_error_and_log!(
      "revocation list {uri}: not issued by the identity CA"
    ));
  }
  let key = ca
    .public_key()
    .map_err(|e| create_security_error_and_log!("revocation list {uri}: the CA's key: {e}"))?;
  match crl.verify(&key) {
    Ok(true) => Ok(crl),
    _ => Err(create_security_error_and_log!(
      "revocation list {uri}: its signature does not verify against the identity CA"
    )),
  }
}
