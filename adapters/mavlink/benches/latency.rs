//! The latency the MAVLink adapter adds: from `apply(setpoint)` (a DDS sample accepted by the
//! vehicle's arbiter) to the RC_CHANNELS_OVERRIDE datagram arriving on a UDP socket on
//! loopback, which stands in for the autopilot. Run with
//! `cargo bench -p rove-mavlink --bench latency` (loopback UDP only; no DDS involved).
//!
//! Prints n, mean, p50, p99, max in microseconds. The arbiter's own decision is measured by the
//! core's criterion bench; DDS delivery by `rove bench handover`.

use mavlink::dialects::ardupilotmega::{
    HEARTBEAT_DATA, MavAutopilot, MavMessage, MavModeFlag, MavState, MavType,
};
use mavlink::{MavHeader, MavlinkVersion};
use rove_core::MonoTime;
use rove_core::adapter::OutputAdapter;
use rove_core::arbiter::Setpoint;
use rove_core::msg::{Mode, MovementCommand};
use rove_mavlink::{MavlinkSettings, MavlinkVehicle};
use std::net::UdpSocket;
use std::time::{Duration, Instant};

const SAMPLES: usize = 20_000;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let autopilot = UdpSocket::bind("127.0.0.1:0")?;
    autopilot.set_read_timeout(Some(Duration::from_secs(2)))?;
    let port = autopilot.local_addr()?.port();
    let mut settings: MavlinkSettings = toml::from_str(&format!(
        "connection = \"udpout:127.0.0.1:{port}\"\nrate_hz = 1\n[modes]\nset_mode = false"
    ))?;
    let start = Instant::now();
    let now = || MonoTime::ZERO + start.elapsed();
    let mut v = MavlinkVehicle::new(settings.validate()?, now())?;
    // Learn the adapter's address from its first heartbeat, then introduce ourselves.
    let mut buf = [0u8; 512];
    let peer = loop {
        let _ = v.keepalive(now());
        if let Ok((_, from)) = autopilot.recv_from(&mut buf) {
            break from;
        }
    };
    let mut hb = Vec::new();
    mavlink::write_versioned_msg(
        &mut hb,
        MavlinkVersion::V2,
        MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 0,
        },
        &MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode: 0,
            mavtype: MavType::MAV_TYPE_GROUND_ROVER,
            autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
            base_mode: MavModeFlag::empty(),
            system_status: MavState::MAV_STATE_ACTIVE,
            mavlink_version: 3,
        }),
    )?;
    while v.link_status().autopilot.is_none() {
        autopilot.send_to(&hb, peer)?;
        std::thread::sleep(Duration::from_millis(5));
    }
    // Drain what the adapter sent while it was discovering us.
    autopilot.set_read_timeout(Some(Duration::from_millis(50)))?;
    while autopilot.recv_from(&mut buf).is_ok() {}
    autopilot.set_read_timeout(Some(Duration::from_secs(2)))?;

    let mut lat = Vec::with_capacity(SAMPLES);
    for i in 0..SAMPLES {
        let sp = Setpoint {
            movement: MovementCommand {
                throttle: (i % 30_000) as i16,
                roll: 0,
                pitch: 0,
                yaw: 0,
            },
            mode: Mode::Manual,
        };
        let t0 = Instant::now();
        v.apply(now(), &sp)?;
        // The override is the first datagram of each apply (heartbeats come at most 1/s).
        loop {
            let (n, _) = autopilot.recv_from(&mut buf)?;
            // RC_CHANNELS_OVERRIDE is message id 70: byte 7 of a v2 frame.
            if n > 9 && buf[0] == 0xFD && buf[7] == 70 {
                break;
            }
        }
        lat.push(t0.elapsed());
    }
    lat.sort();
    let us = |d: Duration| d.as_secs_f64() * 1e6;
    let mean = lat.iter().map(|d| us(*d)).sum::<f64>() / lat.len() as f64;
    let pct = |p: f64| us(lat[((lat.len() as f64 * p) as usize).min(lat.len() - 1)]);
    println!(
        "mavlink apply → RC_CHANNELS_OVERRIDE on the autopilot's socket (loopback UDP): n={} \
         mean={mean:.1} µs p50={:.1} µs p99={:.1} µs max={:.1} µs",
        lat.len(),
        pct(0.50),
        pct(0.99),
        us(lat[lat.len() - 1])
    );
    Ok(())
}
