//! Config text of every kind (vehicle with each adapter's `[output]`, operator with each
//! `[input]`) through the gateway's loader, [`rove_gateway::config::any_from_text`]: the path
//! `rove check-config` and both roles take, from text instead of a file.
//!
//! Checked, besides "no panic": a failure says something (its message is not empty); a success
//! gives an effective config that loads again as the same config and is a fixed point (as
//! `every_shipped_config_loads` checks for the shipped files).

use rove_gateway::config::any_from_text;
use std::path::Path;

/// Loads `data` as a config file's text.
pub fn config(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let path = Path::new("fuzz.toml");
    match any_from_text(path, text) {
        Err(e) => {
            let message = format!("{e:#}");
            assert!(
                !message
                    .trim()
                    .trim_start_matches("fuzz.toml:")
                    .trim()
                    .is_empty(),
                "empty error for {text:?}"
            );
        }
        Ok((config, effective)) => {
            let (again, effective_again) = any_from_text(Path::new("effective.toml"), &effective)
                .unwrap_or_else(|e| {
                    panic!("{e:#}\n--- effective:\n{effective}\n--- from:\n{text}")
                });
            assert_eq!(
                format!("{again:?}"),
                format!("{config:?}"),
                "effective config loads as another\n--- effective:\n{effective}\n--- from:\n{text}"
            );
            assert_eq!(
                effective_again, effective,
                "not a fixed point\n--- from:\n{text}"
            );
        }
    }
}
