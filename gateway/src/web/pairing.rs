//! Pairing codes and session tokens of the browser console, with no I/O: every call takes the
//! time, and randomness comes from the caller.
//!
//! - **One code at a time**, six digits, shown in the operator's log and console. It is valid
//!   for [`CODE_LIFETIME`], for one pairing, and for [`CODE_ATTEMPTS`] wrong guesses. After
//!   those, pairing is closed for [`CODE_COOLDOWN`] before a new code is made: a guesser gets
//!   5 tries in a million per 30 s, about 70 days for even odds, each try logged.
//! - **A pairing** binds a new token (128 random bits, hex) to one configured device: the first
//!   one not paired, else the one paired longest ago whose browser is not connected now (its
//!   old token stops working). A connected device is never taken over.
//! - **A token** is good for the configured session length from its pairing; after that it
//!   is refused as expired, and the browser pairs again. Tokens live in memory: a restart of
//!   the operator unpairs every browser.

use rove_core::time::MonoTime;
use std::collections::HashMap;
use std::time::Duration;

/// How long a pairing code is valid.
pub const CODE_LIFETIME: Duration = Duration::from_secs(600);

/// Wrong codes tried before the code is replaced.
pub const CODE_ATTEMPTS: u32 = 5;

/// How long pairing stays closed after [`CODE_ATTEMPTS`] wrong codes.
pub const CODE_COOLDOWN: Duration = Duration::from_secs(30);

/// Why a pairing was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PairError {
    /// Not the code shown (or an old one).
    #[error("wrong pairing code")]
    WrongCode,
    /// Every device has a connected browser.
    #[error("every [[web.device]] has a browser connected: add a device to [web] or close one")]
    AllInUse,
}

/// Why a token was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TokenError {
    /// Never issued, or replaced by a later pairing of its device, or issued before a restart.
    #[error("unknown session token: pair this browser again")]
    Unknown,
    /// Its session is over.
    #[error("session expired: pair this browser again")]
    Expired,
}

#[derive(Debug, Clone)]
struct Paired {
    device: usize,
    since: MonoTime,
}

/// Codes and tokens (module docs).
#[derive(Debug)]
pub struct Pairing {
    devices: usize,
    session: Duration,
    code: String,
    code_made: MonoTime,
    failures: u32,
    /// When the last wrong code came.
    last_failure: MonoTime,
    /// The code paired a browser: the next one needs a new code.
    used: bool,
    tokens: HashMap<String, Paired>,
}

/// Six decimal digits from random bytes.
fn code_from(random: [u8; 16]) -> String {
    let n = u32::from_le_bytes([random[0], random[1], random[2], random[3]]) % 1_000_000;
    format!("{n:06}")
}

fn token_from(random: [u8; 16]) -> String {
    random.iter().map(|b| format!("{b:02x}")).collect()
}

impl Pairing {
    /// `devices` configured devices, sessions of `session`, a first code from `random`.
    pub fn new(now: MonoTime, devices: usize, session: Duration, random: [u8; 16]) -> Pairing {
        Pairing {
            devices,
            session,
            code: code_from(random),
            code_made: now,
            failures: 0,
            last_failure: now,
            used: false,
            tokens: HashMap::new(),
        }
    }

    /// The code to show now.
    pub fn code(&self) -> &str {
        &self.code
    }

    /// Whether the code must be replaced now: too old, used, or guessed wrong too often and
    /// the cooldown over.
    pub fn code_stale(&self, now: MonoTime) -> bool {
        let cooled = now.saturating_since(self.last_failure) >= CODE_COOLDOWN;
        self.expired(now) || self.used || (self.burnt() && cooled)
    }

    fn expired(&self, now: MonoTime) -> bool {
        now.saturating_since(self.code_made) >= CODE_LIFETIME
    }

    fn burnt(&self) -> bool {
        self.failures >= CODE_ATTEMPTS
    }

    /// Replaces the code; returns the new one.
    pub fn renew(&mut self, now: MonoTime, random: [u8; 16]) -> &str {
        self.code = code_from(random);
        self.code_made = now;
        self.failures = 0;
        self.used = false;
        &self.code
    }

    /// Pairs a browser that typed `code`: its token and device index. `connected(i)` tells
    /// whether device `i` has a browser now. The caller renews the code after a pairing and
    /// whenever [`code_stale`](Self::code_stale).
    ///
    /// # Errors
    /// [`PairError`].
    pub fn pair(
        &mut self,
        now: MonoTime,
        code: &str,
        connected: impl Fn(usize) -> bool,
        random: [u8; 16],
    ) -> Result<(String, usize), PairError> {
        let closed = self.expired(now) || self.used || self.burnt();
        if closed || code.trim() != self.code {
            self.failures = self.failures.saturating_add(1);
            self.last_failure = now;
            return Err(PairError::WrongCode);
        }
        self.tokens
            .retain(|_, p| now.saturating_since(p.since) < self.session);
        let since = |d: usize| {
            self.tokens
                .values()
                .filter(|p| p.device == d)
                .map(|p| p.since)
                .max()
        };
        let free = (0..self.devices).find(|&d| since(d).is_none());
        let device = free
            .or_else(|| {
                (0..self.devices)
                    .filter(|&d| !connected(d))
                    .min_by_key(|&d| since(d))
            })
            .ok_or(PairError::AllInUse)?;
        self.tokens.retain(|_, p| p.device != device);
        let token = token_from(random);
        self.tokens
            .insert(token.clone(), Paired { device, since: now });
        // Used: the next browser needs the next code.
        self.used = true;
        Ok((token, device))
    }

    /// The device `token` speaks for.
    ///
    /// # Errors
    /// [`TokenError`].
    pub fn check(&self, now: MonoTime, token: &str) -> Result<usize, TokenError> {
        let paired = self.tokens.get(token).ok_or(TokenError::Unknown)?;
        if now.saturating_since(paired.since) >= self.session {
            return Err(TokenError::Expired);
        }
        Ok(paired.device)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SESSION: Duration = Duration::from_secs(3600);

    fn s(t: u64) -> MonoTime {
        MonoTime::from_millis(t * 1000)
    }

    fn rnd(n: u8) -> [u8; 16] {
        [n; 16]
    }

    #[test]
    fn a_code_pairs_once_and_its_token_works_until_the_session_ends() {
        let mut p = Pairing::new(s(0), 2, SESSION, rnd(1));
        let code = p.code().to_string();
        assert_eq!(code.len(), 6);
        let (token, device) = p.pair(s(1), &code, |_| false, rnd(2)).expect("paired");
        assert_eq!(device, 0);
        assert_eq!(token.len(), 32);
        assert!(p.code_stale(s(1)), "used: a new code is due");
        assert_eq!(
            p.pair(s(1), &code, |_| false, rnd(3)),
            Err(PairError::WrongCode)
        );
        assert_eq!(p.check(s(3600), &token), Ok(0));
        assert_eq!(p.check(s(3601), &token), Err(TokenError::Expired));
        assert_eq!(p.check(s(2), "00ff"), Err(TokenError::Unknown));
    }

    #[test]
    fn five_wrong_codes_close_pairing_for_the_cooldown_then_a_new_code_works() {
        let mut p = Pairing::new(s(0), 1, SESSION, rnd(1));
        let right = p.code().to_string();
        for _ in 0..CODE_ATTEMPTS {
            assert!(!p.code_stale(s(1)));
            assert!(p.pair(s(1), "000000x", |_| false, rnd(2)).is_err());
        }
        // Burnt: even the right code fails, and no new code until the cooldown is over.
        let refused = p.pair(s(1), &right, |_| false, rnd(2));
        assert_eq!(refused, Err(PairError::WrongCode));
        assert!(!p.code_stale(s(30)));
        assert!(p.code_stale(s(31)));
        let renewed = p.renew(s(31), rnd(9)).to_string();
        assert!(!p.code_stale(s(31)));
        assert!(p.pair(s(31), &renewed, |_| false, rnd(2)).is_ok());
        assert!(
            p.code_stale(s(31)),
            "used: the next browser needs a new code at once"
        );
    }

    #[test]
    fn codes_expire() {
        let p = Pairing::new(s(0), 1, SESSION, rnd(1));
        assert!(!p.code_stale(s(599)));
        assert!(p.code_stale(s(600)));
    }

    #[test]
    fn devices_are_taken_free_first_then_the_oldest_unconnected_never_a_connected_one() {
        let mut p = Pairing::new(s(0), 2, SESSION, rnd(1));
        let pair = |p: &mut Pairing, t, connected: fn(usize) -> bool, r| {
            let code = p.renew(s(t), rnd(r)).to_string();
            p.pair(s(t), &code, connected, rnd(r + 100))
        };
        let (a, da) = pair(&mut p, 1, |_| false, 1).expect("first");
        let (b, db) = pair(&mut p, 2, |_| false, 2).expect("second");
        assert_eq!((da, db), (0, 1));
        // Both connected: nothing to take.
        assert_eq!(pair(&mut p, 3, |_| true, 3), Err(PairError::AllInUse));
        // Device 0 is not connected: the oldest pairing is replaced and its token revoked.
        let (c, dc) = pair(&mut p, 4, |d| d == 1, 4).expect("third");
        assert_eq!(dc, 0);
        assert_eq!(p.check(s(5), &a), Err(TokenError::Unknown));
        assert_eq!(p.check(s(5), &b), Ok(1));
        assert_eq!(p.check(s(5), &c), Ok(0));
    }

    #[test]
    fn an_expired_pairing_frees_its_device() {
        let mut p = Pairing::new(s(0), 1, Duration::from_secs(10), rnd(1));
        let code = p.code().to_string();
        let (old, _) = p.pair(s(0), &code, |_| true, rnd(2)).expect("paired");
        let code = p.renew(s(11), rnd(3)).to_string();
        // Even "connected" (a stale socket): the session is over, the device is free.
        let (new, d) = p.pair(s(11), &code, |_| true, rnd(4)).expect("repaired");
        assert_eq!(d, 0);
        assert_eq!(p.check(s(11), &old), Err(TokenError::Unknown));
        assert_eq!(p.check(s(11), &new), Ok(0));
    }
}
