//! How long a certificate is valid, and what a fleet's certificates say about it
//! (`rove keys list`, `rove doctor`).
//!
//! Every participant checks the dates of its own certificate and of every peer's when they
//! authenticate (ROVE-PATCH.md, "certificate lifetime"): a device whose certificate expired
//! does not join, and nobody accepts a peer whose certificate expired or is not valid yet.

use anyhow::Context;
use openssl::asn1::{Asn1Time, Asn1TimeRef};
use openssl::x509::X509;
use rove_core::msg::DeviceId;
use std::path::Path;

/// How long and from when a certificate is valid.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Lifetime {
    /// Days from its start.
    pub days: u32,
    /// Test hook: the validity starts this many days from now (negative: in the past), to make
    /// certificates that expired or are not valid yet.
    pub starts_in_days: i64,
}

impl Lifetime {
    /// A device's certificate: a year. `rove doctor` warns 30 days before the end; renew with
    /// `rove keys add --renew`.
    pub const DEVICE: Lifetime = Lifetime {
        days: 365,
        starts_in_days: 0,
    };
    /// The fleet CA: ten years (its end is the fleet's re-keying).
    pub const CA: Lifetime = Lifetime {
        days: 3650,
        starts_in_days: 0,
    };

    /// A device certificate valid for `days` from now.
    pub fn days(days: u32) -> Lifetime {
        Lifetime {
            days,
            ..Lifetime::DEVICE
        }
    }

    /// The start and end: the start is backdated by [`BACKDATE_S`], so that a device whose
    /// clock is a little behind the issuing machine's accepts the certificate at once.
    pub(super) fn period(self) -> anyhow::Result<(Asn1Time, Asn1Time)> {
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .context("the system clock is before 1970")?
            .as_secs();
        let now = i64::try_from(now).context("the system clock is beyond 2262")?;
        let start = now + self.starts_in_days * DAY_S;
        let end = start + i64::from(self.days) * DAY_S;
        // `time_t` is 32 bits on some boards (armhf): a date past 2038 is refused there.
        #[allow(clippy::useless_conversion)]
        let time = |t: i64| t.try_into().context("a date beyond this platform's time_t");
        let from = Asn1Time::from_unix(time(start - BACKDATE_S)?)?;
        let until = Asn1Time::from_unix(time(end)?)?;
        Ok((from, until))
    }
}

const DAY_S: i64 = 86_400;

/// How far back a certificate's start is set: an hour.
pub const BACKDATE_S: i64 = 3_600;

/// `rove doctor` warns when a certificate ends within this many days.
pub const WARN_DAYS: i64 = 30;

/// Where now lies in a certificate's validity.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Expiry {
    /// The end, as OpenSSL prints it (`Nov 26 22:00:00 2027 GMT`).
    pub not_after: String,
    /// Whole days from now to the end (negative once it has passed).
    pub days_left: i64,
    /// Seconds from now to the start (positive while it is not valid yet).
    pub starts_in_s: i64,
}

impl Expiry {
    /// The certificate in `pem`.
    ///
    /// # Errors
    /// It is not a PEM certificate.
    pub fn of(pem: &[u8]) -> anyhow::Result<Expiry> {
        let cert = X509::from_pem(pem).context("not a PEM certificate")?;
        let now = Asn1Time::days_from_now(0)?;
        let seconds = |t: &Asn1TimeRef| -> anyhow::Result<i64> {
            let d = now.diff(t)?;
            Ok(i64::from(d.days) * DAY_S + i64::from(d.secs))
        };
        let left = seconds(cert.not_after())?;
        Ok(Expiry {
            not_after: cert.not_after().to_string(),
            days_left: left.div_euclid(DAY_S),
            starts_in_s: seconds(cert.not_before())?,
        })
    }

    /// In words: valid until …, expired on …, or not valid yet.
    pub fn describe(&self) -> String {
        if self.starts_in_s > 0 {
            format!("not valid yet (starts in {} s)", self.starts_in_s)
        } else if self.days_left < 0 {
            format!("EXPIRED on {}", self.not_after)
        } else {
            format!("valid until {} ({} days)", self.not_after, self.days_left)
        }
    }

    /// Valid now.
    pub fn valid(&self) -> bool {
        self.starts_in_s <= 0 && self.days_left >= 0
    }
}

/// One device of a fleet, as `rove keys list` shows it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Issued {
    /// The device id (its directory's name).
    pub id: DeviceId,
    /// Its certificate's validity.
    pub expiry: Expiry,
    /// The fleet's revocation list names it.
    pub revoked: bool,
}

/// The devices issued in fleet directory `dir`, by id.
///
/// # Errors
/// `dir` cannot be read, or a device's certificate cannot be.
pub fn list(dir: &Path) -> anyhow::Result<Vec<Issued>> {
    let mut found = Vec::new();
    let revoked = super::revocation::read_list(dir)?;
    let entries = std::fs::read_dir(dir).with_context(|| format!("read {}", dir.display()))?;
    for entry in entries {
        let entry = entry?;
        let Some(id) = (entry.file_name().to_str()).and_then(|n| n.parse::<DeviceId>().ok()) else {
            continue;
        };
        let path = entry.path().join("cert.pem");
        if !path.exists() {
            continue;
        }
        let pem = std::fs::read(&path).with_context(|| format!("read {}", path.display()))?;
        let expiry = Expiry::of(&pem).with_context(|| path.display().to_string())?;
        found.push(Issued {
            id,
            expiry,
            revoked: super::revocation::names(revoked.as_ref(), &pem)?,
        });
    }
    found.sort_by_key(|i| i.id);
    Ok(found)
}
