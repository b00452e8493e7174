//! The crate's error types: configuration problems (collected, each naming its key) and the
//! classified errors output adapters and input sources report.

use std::fmt;

/// Result alias for fallible `rove-core` functions.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Errors from `rove-core`'s own functions.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Error {
    /// A configuration value (or several) is invalid. Each entry names its key path; the operator
    /// should fix those keys in the file named by the caller.
    #[error("{0}")]
    Config(ConfigErrors),
    /// A hierarchy fine offset outside 0..=9 was asked for; check the operator's
    /// `hierarchy.offset` key.
    #[error("hierarchy fine offset {offset} is out of range: must be 0..=9")]
    OffsetOutOfRange {
        /// The offending offset.
        offset: u8,
    },
}

/// One invalid configuration value: which key, what value, which rule it breaks.
///
/// Displayed as `key = value: rule`, e.g. `hierarchy.mobile.laptop = 315: must be ≥ 320 …`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConfigError {
    /// Dotted key path relative to the file's root, e.g. `output.channels[2].max_us`.
    pub key: String,
    /// The value as written (or computed from what was written).
    pub value: String,
    /// The rule it breaks, phrased as what it must be.
    pub rule: String,
}

impl ConfigError {
    /// A new error for `key` holding `value`, breaking `rule`.
    pub fn new(key: impl Into<String>, value: impl fmt::Display, rule: impl Into<String>) -> Self {
        ConfigError {
            key: key.into(),
            value: value.to_string(),
            rule: rule.into(),
        }
    }

    /// The same error with `prefix.` put before its key, for nested sections.
    pub fn within(mut self, prefix: &str) -> Self {
        if !prefix.is_empty() {
            self.key = format!("{prefix}.{}", self.key);
        }
        self
    }
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} = {}: {}", self.key, self.value, self.rule)
    }
}

/// Every problem found in one validation pass: validation collects them all before failing, so
/// the operator fixes a file in one edit rather than one error per run.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ConfigErrors(pub Vec<ConfigError>);

impl ConfigErrors {
    /// Records a problem.
    pub fn push(&mut self, error: ConfigError) {
        self.0.push(error);
    }

    /// Records `key = value: rule`.
    pub fn add(
        &mut self,
        key: impl Into<String>,
        value: impl fmt::Display,
        rule: impl Into<String>,
    ) {
        self.push(ConfigError::new(key, value, rule));
    }

    /// Records every problem of a nested section under `prefix`.
    pub fn extend_within(&mut self, prefix: &str, errors: ConfigErrors) {
        self.0
            .extend(errors.0.into_iter().map(|e| e.within(prefix)));
    }

    /// `Ok(value)` if nothing was recorded, else all recorded problems.
    ///
    /// # Errors
    /// Returns [`Error::Config`] holding every recorded problem.
    pub fn into_result<T>(self, value: T) -> Result<T> {
        if self.0.is_empty() {
            Ok(value)
        } else {
            Err(Error::Config(self))
        }
    }
}

impl fmt::Display for ConfigErrors {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, e) in self.0.iter().enumerate() {
            if i > 0 {
                writeln!(f)?;
            }
            write!(f, "{e}")?;
        }
        Ok(())
    }
}

/// How an I/O failure of an adapter or input should be handled; decided by a pure `classify`
/// function in each adapter so that the policy is unit-tested.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Disposition {
    /// Routine (a read timeout, would-block): not logged, not counted.
    Silent,
    /// The link or device failed but may come back: go safe, report, retry.
    Transient,
    /// Retrying cannot help (bad configuration, missing permission): report and stop retrying.
    Fatal,
}

/// A failure reported by an output adapter or an input source.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{detail}")]
pub struct LinkError {
    /// How the caller should react.
    pub disposition: Disposition,
    /// What failed, naming the device, path or address.
    pub detail: String,
}

impl LinkError {
    /// A failure that may clear by itself (device unplugged, link down, bus-off).
    pub fn transient(detail: impl Into<String>) -> Self {
        LinkError {
            disposition: Disposition::Transient,
            detail: detail.into(),
        }
    }

    /// A failure retrying cannot fix.
    pub fn fatal(detail: impl Into<String>) -> Self {
        LinkError {
            disposition: Disposition::Fatal,
            detail: detail.into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_errors_name_key_value_and_rule() {
        let mut errors = ConfigErrors::default();
        errors.push(ConfigError::new(
            "max_us",
            900,
            "must be greater than centre_us (1500)",
        ));
        let mut outer = ConfigErrors::default();
        outer.extend_within("output.channels[2]", errors);
        let err = outer.into_result(()).expect_err("one error recorded");
        assert_eq!(
            err.to_string(),
            "output.channels[2].max_us = 900: must be greater than centre_us (1500)"
        );
    }

    #[test]
    fn empty_errors_are_ok() {
        assert_eq!(ConfigErrors::default().into_result(5), Ok(5));
    }
}
