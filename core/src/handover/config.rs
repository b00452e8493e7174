//! The handover settings: `[handover]` as written ([`HandoverSettings`]), validated into
//! [`HandoverConfig`], and the auto-accept policy ([`AutoAccept`]).

use crate::error::{ConfigError, ConfigErrors, Result};
use serde::{Deserialize, Serialize};
use std::time::Duration;

/// When the owner's operator gives control without asking a person.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AutoAccept {
    /// Always ask the operator.
    Never,
    /// Accept at once when the requester's priority exceeds our strength; else ask.
    #[default]
    HigherPriority,
    /// Always accept (unattended stations).
    Always,
}

/// `[handover]` as written in TOML; absent keys take defaults.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HandoverSettings {
    /// Auto-accept policy.
    pub auto_accept: Option<AutoAccept>,
    /// How long a person has to answer a request before it is refused.
    pub consent_timeout_ms: Option<crate::config::Int>,
    /// How long a requester waits for an answer before giving up.
    pub reply_timeout_ms: Option<crate::config::Int>,
    /// How often an unanswered REQUEST is sent again.
    pub resend_ms: Option<crate::config::Int>,
}

/// Validated handover settings.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HandoverConfig {
    /// Auto-accept policy.
    pub auto_accept: AutoAccept,
    /// Default 10 s: long enough to read a prompt and decide, short enough that a requester
    /// whose operator is away is not left waiting.
    pub consent_timeout: Duration,
    /// Default 12 s: the consent timeout plus margin for the REFUSE to arrive, so a requester
    /// normally hears the refusal rather than timing out on its own.
    pub reply_timeout: Duration,
    /// Default 500 ms: RequestControl has default QoS (possibly best-effort), so a lost REQUEST
    /// is repeated well inside a person's patience; more often only adds traffic.
    pub resend: Duration,
}

impl Default for HandoverConfig {
    fn default() -> Self {
        HandoverConfig {
            auto_accept: AutoAccept::HigherPriority,
            consent_timeout: Duration::from_secs(10),
            reply_timeout: Duration::from_secs(12),
            resend: Duration::from_millis(500),
        }
    }
}

impl HandoverSettings {
    /// Validates, filling defaults. Keys are named relative to the `[handover]` table.
    ///
    /// # Errors
    /// [`crate::Error::Config`] for a zero duration, a consent timeout over 10 minutes, a reply
    /// timeout not longer than the consent timeout, or a resend period not shorter than the reply
    /// timeout.
    pub fn validate(&self) -> Result<HandoverConfig> {
        let d = HandoverConfig::default();
        let mut errors = ConfigErrors::default();
        // Read wide (the config integer policy): a negative value is reported with its key, and
        // the default stands in so that the checks below do not repeat it.
        let mut ms = |key: &str, v: Option<crate::config::Int>, default: Duration| {
            let v = v.map(|v| errors.int(key, v, 0..=crate::config::Int::MAX, " ms"));
            v.flatten().map_or(default, Duration::from_millis)
        };
        let config = HandoverConfig {
            auto_accept: self.auto_accept.unwrap_or(d.auto_accept),
            consent_timeout: ms(
                "consent_timeout_ms",
                self.consent_timeout_ms,
                d.consent_timeout,
            ),
            reply_timeout: ms("reply_timeout_ms", self.reply_timeout_ms, d.reply_timeout),
            resend: ms("resend_ms", self.resend_ms, d.resend),
        };
        let show = |d: Duration| d.as_millis();
        if config.consent_timeout.is_zero() || config.consent_timeout > Duration::from_secs(600) {
            errors.push(ConfigError::new(
                "consent_timeout_ms",
                show(config.consent_timeout),
                "must be 1..=600000",
            ));
        }
        if config.reply_timeout <= config.consent_timeout {
            errors.push(ConfigError::new(
                "reply_timeout_ms",
                show(config.reply_timeout),
                format!(
                    "must be longer than consent_timeout_ms ({}) so the requester hears the \
                     refusal instead of timing out",
                    show(config.consent_timeout)
                ),
            ));
        }
        if config.resend.is_zero() || config.resend >= config.reply_timeout {
            errors.push(ConfigError::new(
                "resend_ms",
                show(config.resend),
                format!(
                    "must be at least 1 and shorter than reply_timeout_ms ({})",
                    show(config.reply_timeout)
                ),
            ));
        }
        errors.into_result(config)
    }
}
