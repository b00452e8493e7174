//! The operator's local API end to end: two operators and a vehicle as processes, in
//! a network namespace of the test's own; the operators are driven only through their Unix
//! sockets (newline-delimited JSON, docs/api.md), as a web or mobile front end would.

use crate::util::{Rig, eventually, records, wait_for_output, wall_us};
use serde_json::{Value, json};
use std::io::{BufRead, BufReader, Write};
use std::os::unix::net::UnixStream;
use std::path::{Path, PathBuf};
use std::time::Duration;

const V: i64 = 100;
const A: i64 = 11;
const B: i64 = 21;

/// A client of one operator's API: every line it has read, in order.
pub(crate) struct Api {
    writer: UnixStream,
    reader: BufReader<UnixStream>,
    lines: Vec<Value>,
}

impl Api {
    pub(crate) fn connect(path: &Path) -> Api {
        let stream = eventually(&format!("connect to {}", path.display()), || {
            UnixStream::connect(path)
        });
        stream
            .set_read_timeout(Some(Duration::from_millis(100)))
            .expect("timeout");
        Api {
            writer: stream.try_clone().expect("clone"),
            reader: BufReader::new(stream),
            lines: Vec::new(),
        }
    }

    /// Reads what has arrived; returns whether a line came.
    fn pump(&mut self) -> bool {
        let mut line = String::new();
        match self.reader.read_line(&mut line) {
            Ok(n) if n > 0 => {
                let v: Value = serde_json::from_str(line.trim())
                    .unwrap_or_else(|e| panic!("API line is not JSON ({e}): {line}"));
                self.lines.push(v);
                true
            }
            _ => false,
        }
    }

    pub(crate) fn wait(&mut self, what: &str, pred: impl Fn(&Value) -> bool) -> Value {
        self.wait_from(0, what, pred)
    }

    /// Reads every line that has arrived; returns how many there are, for [`Api::wait_from`].
    pub(crate) fn mark(&mut self) -> usize {
        while self.pump() {}
        self.lines.len()
    }

    /// As [`Api::wait`], for a line after the first `from`.
    pub(crate) fn wait_from(
        &mut self,
        from: usize,
        what: &str,
        pred: impl Fn(&Value) -> bool,
    ) -> Value {
        let mut seen = from;
        eventually(what, || {
            while seen < self.lines.len() {
                if pred(&self.lines[seen]) {
                    return Ok(self.lines[seen].clone());
                }
                seen += 1;
            }
            self.pump();
            Err(format!("lines: {:#?}", self.lines))
        })
    }

    /// Sends one command line and returns its reply (`ok` or `error`).
    pub(crate) fn send(&mut self, line: &str) -> Value {
        let from = self.lines.len();
        self.writer
            .write_all(format!("{line}\n").as_bytes())
            .expect("write");
        eventually(&format!("a reply to {line}"), || {
            if let Some(reply) = self.lines[from..]
                .iter()
                .find(|v| v.get("ok").is_some() || v.get("error").is_some())
            {
                return Ok(reply.clone());
            }
            self.pump();
            Err(format!("lines since: {:#?}", &self.lines[from..]))
        })
    }
}

/// The vehicle (driven by A), A (asks its person: auto_accept never, 3 s consent timeout)
/// and B (weaker, drives nothing), each operator with an API socket.
fn rig(test: &str) -> (Rig, PathBuf, Api, Api) {
    let mut rig = Rig::new(test);
    let record = rig.vehicle(V);
    rig.operator(
        A,
        "stationary",
        "laptop",
        &[V],
        1000,
        "[handover]\nauto_accept = \"never\"\nconsent_timeout_ms = 3000\n\
         [console]\napi_socket = \"a.sock\"\n",
        &[],
    );
    rig.operator(
        B,
        "remote",
        "desktop",
        &[],
        2000,
        "[console]\napi_socket = \"b.sock\"\n",
        &[],
    );
    wait_for_output(&record, Some(A), 0).expect("A drives");
    let a = Api::connect(&rig.dir.join("a.sock"));
    let mut b = Api::connect(&rig.dir.join("b.sock"));
    b.wait("B sees the vehicle driven by A", |v| {
        v["event"] == "device" && v["id"] == V && v["owner"] == A
    });
    // The vehicle's VehicleStatus reaches the console: its mode and output health.
    b.wait("B sees the vehicle's status", |v| {
        v["event"] == "vehicle_status"
            && v["vehicle"] == V
            && v["mode"] == "manual"
            && v["failsafe"] == false
            && v["link"] == "ok"
    });
    // Where it stands for B, in the words every console shows (B drives nothing).
    b.wait("B's standing: A drives", |v| {
        v["event"] == "standing"
            && v["vehicle"] == V
            && v["state"] == "driven"
            && v["other"] == A
            && v["safe"] == false
            && v["text"]
                .as_str()
                .is_some_and(|t| t.starts_with("driven by ") && t.ends_with(&format!("({A})")))
    });
    (rig, record, a, b)
}

/// One meaning of "online" (issue 33): a crashed operator leaves the other operator's device
/// list (its console, API and web page share that state) when its participant is lost: its
/// SPDP lease (1 s at the default `presence_ms`) runs out, checked every quarter lease. Not
/// the backstop, three DeviceInfo refreshes (15 s). Measured from the SIGKILL.
#[test]
fn a_crashed_operator_leaves_the_other_operators_list_when_its_participant_is_lost() {
    let (mut rig, _record, _a, mut b) = rig("api-crash");
    // The rig's processes in start order: the vehicle, then A.
    let crashed = wall_us();
    rig.procs[1].crash();
    b.wait("A leaves B's list", |v| {
        v["event"] == "device_gone" && v["id"] == A
    });
    let after_ms = (wall_us() - crashed) / 1000;
    eprintln!("A left B's list {after_ms} ms after it was killed");
    assert!(
        after_ms < 5_000,
        "A left B's list {after_ms} ms after the crash: the backstop, not the participant's loss"
    );
}

#[test]
fn b_requests_a_accepts_b_drives_then_finish_gives_it_back() {
    let (_rig, record, mut a, mut b) = rig("api-accept");
    assert_eq!(
        b.send(&json!({"cmd": "request", "vehicle": V}).to_string())["ok"],
        true
    );
    let prompt = a.wait("the request reaches A", |v| {
        v["event"] == "request_incoming"
    });
    assert_eq!(
        (prompt["vehicle"].as_i64(), prompt["from"].as_i64()),
        (Some(V), Some(B))
    );
    assert!(
        prompt["timeout_ms"].as_u64().is_some_and(|t| t <= 3000),
        "{prompt}"
    );

    let t = wall_us();
    assert_eq!(
        a.send(&json!({"cmd": "accept", "vehicle": V}).to_string())["ok"],
        true
    );
    let driven = wait_for_output(&record, Some(B), t).expect("B drives after the ACCEPT");
    assert_eq!(driven.throttle, Some(2000));
    b.wait("B's request ended accepted", |v| {
        v["event"] == "request_ended" && v["outcome"] == "accepted"
    });
    b.wait("B holds the grant", |v| {
        v["event"] == "driving" && v["holding"] == json!([V])
    });

    let t = wall_us();
    assert_eq!(
        b.send(&json!({"cmd": "finish", "vehicle": V}).to_string())["ok"],
        true
    );
    wait_for_output(&record, Some(A), t).expect("FINISH gives the vehicle back to A");
}

#[test]
fn a_refuses_and_the_vehicle_stays_with_a() {
    let (_rig, record, mut a, mut b) = rig("api-refuse");
    let t = wall_us();
    assert_eq!(b.send(r#"{"cmd":"request","vehicle":100}"#)["ok"], true);
    a.wait("prompt", |v| v["event"] == "request_incoming");
    assert_eq!(a.send(r#"{"cmd":"refuse","vehicle":100}"#)["ok"], true);
    b.wait("B hears the refusal", |v| {
        v["event"] == "request_ended" && v["outcome"] == "refused"
    });
    assert!(
        records(&record)
            .iter()
            .all(|o| o.wall_us < t || o.owner != Some(B)),
        "B never drove"
    );
}

#[test]
fn an_unanswered_request_times_out_as_refused() {
    let (_rig, record, mut a, mut b) = rig("api-timeout");
    let t = wall_us();
    assert_eq!(b.send(r#"{"cmd":"request","vehicle":100}"#)["ok"], true);
    a.wait("prompt", |v| v["event"] == "request_incoming");
    let closed = a.wait("A's prompt closes at the consent timeout", |v| {
        v["event"] == "prompt_closed"
    });
    assert_eq!(closed["outcome"], "timed_out", "{closed}");
    b.wait("B is refused", |v| {
        v["event"] == "request_ended" && v["outcome"] == "refused"
    });
    let waited_ms = (wall_us() - t) / 1000;
    assert!(
        waited_ms >= 2500,
        "refused only after the 3 s consent timeout ({waited_ms} ms)"
    );
    assert!(
        records(&record)
            .iter()
            .all(|o| o.wall_us < t || o.owner != Some(B))
    );
}

#[test]
fn malformed_api_input_gets_json_errors_and_the_operator_keeps_working() {
    let (mut rig, record, mut a, _b) = rig("api-malformed");
    for bad in [
        "not json",
        "{}",
        r#"{"cmd":"fly"}"#,
        r#"{"cmd":"accept"}"#,
        r#"{"cmd":"drive","vehicle":"x"}"#,
        r#"{"cmd":"accept","vehicle":100}"#,
        "[1,2,3]",
    ] {
        let reply = a.send(bad);
        assert!(reply["error"].is_string(), "{bad} → {reply}");
        assert!(reply["code"].is_string(), "{bad} → {reply}");
    }
    let long = "x".repeat(70_000);
    let reply = a.send(&long);
    assert!(reply["error"].is_string(), "over-long line → {reply}");
    // Still alive and still driving.
    assert!(rig.procs[1].is_running(), "operator A survived");
    let t = wall_us();
    wait_for_output(&record, Some(A), t).expect("A still drives");
    assert_eq!(a.send(r#"{"cmd":"mode","mode":"assisted"}"#)["ok"], true);
}
