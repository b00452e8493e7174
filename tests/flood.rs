//! Floods of well-formed samples (issue 29, item 4): a hundred writers weaker than the owner, in
//! one foreign participant (Cyclone DDS, `testkit/rogue.py flood`), send ControlCommand to the
//! vehicle an honest laptop (id 11) drives, 10 000 samples a second in bursts (each writer's
//! two samples of a period in one datagram, as a DDS that batches writes sends them), and
//! RequestControl REQUESTs that nobody answers, while the laptop hands the vehicle over to a
//! tablet and gets it back (REQUEST, ACCEPT, FINISH). No `[access]`: the flood's strength is one
//! the hierarchy can give, so only the owner's own samples keep it the owner.
//!
//! Every operator writes the same ControlCommand instance (key = the vehicle's id) and
//! RequestControl has no key. Before rove's patch of rustdds (`vendor/rustdds/ROVE-PATCH.md`
//! §12) a flood shared one history with the owner: whenever the vehicle's loop fell more than
//! that history behind, the owner's samples were the ones pushed out. Now each writer has a
//! room of its own in both histories.

use crate::util::{PATIENCE, Rig, foreign_summary, records, wait_for_output, wall_us};
use std::io::{BufRead, BufReader};
use std::process::Stdio;
use std::sync::mpsc;
use std::time::Instant;

const V: i64 = 100;
const LAPTOP: i64 = 11;
const TABLET: i64 = 13;
/// The flood's ids: command writers from here, request writers from here + 10 000.
const FLOOD_ID: i64 = 1000;
const FLOOD_WRITERS: i64 = 100;
/// Datagrams per second from each flooding writer, and samples in each: 100 × 50 × 2 =
/// 10 000 commands a second.
const FLOOD_HZ: &str = "50";
const FLOOD_BATCH: &str = "2";
/// REQUESTs per second from each of the flood's 100 RequestControl writers.
const FLOOD_REQUEST_HZ: &str = "10";
/// How long the flood lasts (s): the peer stops by itself.
const FLOOD_SECONDS: &str = "10";
const ROGUE_THROTTLE: i64 = 31111;
/// The longest the vehicle may go without applying a command (ms): the command timeout (100 ms)
/// plus a little over two periods of the owner's 50 Hz stream.
const MAX_GAP_MS: f64 = 150.0;

#[test]
fn a_flood_from_a_hundred_weaker_writers_neither_stops_the_owner_nor_loses_a_handover() {
    let mut rig = Rig::new("flood");
    let record = rig.vehicle(V);
    let always = "[handover]\nauto_accept = \"always\"\n";
    rig.operator(LAPTOP, "stationary", "laptop", &[V], 1000, always, &[]);
    wait_for_output(&record, Some(LAPTOP), 0).expect("the laptop drives");

    // Remote desktop (110): weaker than the stationary laptop (220), inside the hierarchy.
    let (first, writers) = (FLOOD_ID.to_string(), FLOOD_WRITERS.to_string());
    let args = [
        "flood",
        "--writers",
        &writers,
        "--id",
        &first,
        "--strength",
        "110",
        "--dest",
        "100",
        "--hz",
        FLOOD_HZ,
        "--batch",
        FLOOD_BATCH,
        "--requests",
        &writers,
        "--request-hz",
        FLOOD_REQUEST_HZ,
        "--seconds",
        FLOOD_SECONDS,
    ];
    let mut peer = rig
        .foreign_peer(&args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start the flood");
    // It says "flooding" on stderr once its writers are matched.
    let (said, heard) = mpsc::channel();
    let stderr = peer.stderr.take().expect("stderr");
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            let _ = said.send(line);
        }
    });
    let deadline = Instant::now() + PATIENCE;
    let mut told = Vec::new();
    let flooding = loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match heard.recv_timeout(left) {
            Ok(line) if line.contains("flooding") => break wall_us(),
            Ok(line) => told.push(line),
            Err(_) => {
                let _ = peer.kill();
                panic!("the flood never started: {told:?}");
            }
        }
    };

    // An active handover while it floods: the tablet asks, the laptop accepts, the tablet
    // drives with its grant, quits (FINISH), and the laptop drives again.
    let asked = wall_us();
    let tablet = rig.operator(
        TABLET,
        "remote",
        "tablet",
        &[],
        3000,
        "",
        &["--request", "100"],
    );
    let granted = wait_for_output(&record, Some(TABLET), asked).expect("the tablet is granted");
    let finished = wall_us();
    rig.procs[tablet].stop();
    let back = wait_for_output(&record, Some(LAPTOP), finished).expect("the laptop drives again");

    // The flood stops by itself after FLOOD_SECONDS.
    let out = peer.wait_with_output().expect("the flood runs to its end");
    let ended = wall_us();
    let summary = foreign_summary(out, &args);
    let sent = summary["samples"].as_f64().expect("samples");
    let requests = summary["requests"].as_f64().expect("requests");
    let flood_s = summary["seconds"].as_f64().expect("seconds");
    let rate = sent / flood_s;

    let outs = records(&record);
    let window: Vec<_> = (outs.iter())
        .filter(|o| o.wall_us >= flooding && o.wall_us <= ended)
        .collect();
    let rogue = window.iter().find(|o| {
        o.throttle == Some(ROGUE_THROTTLE)
            || o.owner
                .is_some_and(|id| (FLOOD_ID..FLOOD_ID + FLOOD_WRITERS).contains(&id))
    });
    let applies: Vec<u64> = (window.iter())
        .filter(|o| o.action == "apply")
        .map(|o| o.wall_us)
        .collect();
    let mut gaps: Vec<f64> = (applies.windows(2))
        .map(|w| (w[1] - w[0]) as f64 / 1000.0)
        .collect();
    gaps.sort_by(f64::total_cmp);
    let max_gap = gaps.last().copied().unwrap_or(f64::INFINITY);
    let p99 = (gaps.get(gaps.len() * 99 / 100).or(gaps.last()))
        .copied()
        .unwrap_or(f64::INFINITY);
    let safe = window.iter().filter(|o| o.action != "apply").count();
    eprintln!(
        "flood: {sent} commands in {flood_s:.1} s ({rate:.0}/s) from {FLOOD_WRITERS} writers, \
         {requests} REQUESTs ({:.0}/s); vehicle: {} applies, {safe} safe outputs, gap max \
         {max_gap:.1} ms, p99 {p99:.1} ms; handover: granted after {:.1} ms, the laptop back \
         {:.1} ms after the tablet's stop",
        requests / flood_s,
        applies.len(),
        (granted.wall_us - asked) as f64 / 1000.0,
        (back.wall_us - finished) as f64 / 1000.0,
    );
    assert!(
        rate >= 5000.0,
        "the flood sent {rate:.0} commands/s, not 5 000: {summary}"
    );
    assert!(
        back.wall_us < ended,
        "the handover was not over before the flood ended"
    );
    assert!(
        rogue.is_none(),
        "a flooding writer's sample was applied: {rogue:?}"
    );
    assert!(
        max_gap <= MAX_GAP_MS,
        "the vehicle went {max_gap:.1} ms without applying a command (p99 {p99:.1} ms)"
    );
}
