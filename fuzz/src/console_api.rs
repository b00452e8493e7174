//! Lines into the console API's command parser
//! ([`rove_console::api::parse_command_bytes`]), as the socket's line reader hands them over:
//! the input is split at newlines and each line parsed.
//!
//! Checked, besides "no panic": a command that parses prints (`command_json`) as a line that
//! parses to the same command; a line that does not parse gets an error reply that is one
//! line of valid JSON.

use rove_console::api::{ApiReply, command_json, parse_command, parse_command_bytes};

/// Parses every line of `data`.
pub fn console_api(data: &[u8]) {
    for (n, line) in data.split(|&b| b == b'\n').enumerate() {
        match parse_command_bytes(line) {
            Ok(command) => {
                let json = command_json(&command);
                assert!(!json.contains('\n'), "{json:?}");
                let again = parse_command(&json)
                    .unwrap_or_else(|e| panic!("{command:?} prints as {json}, which fails: {e}"));
                assert_eq!(again, command, "{json}");
            }
            Err(e) => {
                let reply = ApiReply::parse_error(&e, n as u64 + 1).to_json();
                assert!(!reply.contains('\n'), "{reply:?}");
                let value: serde_json::Value = serde_json::from_str(&reply)
                    .unwrap_or_else(|e| panic!("reply {reply} is not JSON: {e}"));
                let said = value
                    .get("error")
                    .and_then(|v| v.as_str())
                    .unwrap_or_default();
                assert!(!said.trim().is_empty(), "reply without a reason: {reply}");
                assert!(value.get("code").is_some_and(|v| v.is_string()), "{reply}");
            }
        }
    }
}
