//! The latency rove's routing adds between an autopilot and a ground station (`[[output.gcs]]`,
//! docs/mavlink.md "Sharing the autopilot with a ground station"), against a direct link, in one
//! run: `cargo bench -p rove-mavlink --bench routing` (loopback UDP only).
//!
//! Two sockets stand in for the autopilot and the station. One frame in flight at a time: sent,
//! then waited for on the other socket. Autopilot → station carries ATTITUDE (telemetry),
//! station → autopilot COMMAND_LONG. "direct" sends the same frames between the two sockets
//! with nothing between them. Prints n, p50, p99 and max in microseconds for each.

use mavlink::dialects::ardupilotmega::{
    ATTITUDE_DATA, COMMAND_LONG_DATA, HEARTBEAT_DATA, MavAutopilot, MavMessage, MavState, MavType,
};
use mavlink::{MavHeader, MavlinkVersion};
use rove_core::MonoTime;
use rove_core::adapter::OutputAdapter;
use rove_mavlink::{MavlinkSettings, MavlinkVehicle};
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

const SAMPLES: usize = 20_000;
/// ATTITUDE's and COMMAND_LONG's message ids.
const ATTITUDE: u8 = 30;
const COMMAND_LONG: u8 = 76;

fn frame(system_id: u32, sequence: u8, msg: &MavMessage) -> Vec<u8> {
    let mut out = Vec::new();
    let header = MavHeader {
        system_id,
        component_id: 1,
        sequence,
    };
    let _ = mavlink::write_versioned_msg(&mut out, MavlinkVersion::V2, header, msg);
    out
}

/// Waits on `sock` for a v2 frame of message id `id` (other traffic skipped); its sender.
fn receive(sock: &UdpSocket, id: u8) -> std::io::Result<SocketAddr> {
    let mut buf = [0u8; 512];
    loop {
        let (n, from) = sock.recv_from(&mut buf)?;
        if n > 9 && buf[0] == 0xFD && buf[7] == id {
            return Ok(from);
        }
    }
}

/// Sends `frames[i]` from `from` to `to` and times its arrival at `at`, one at a time.
fn time(from: &UdpSocket, to: SocketAddr, at: &UdpSocket, id: u8, frames: &[Vec<u8>]) -> Vec<f64> {
    let mut lat = Vec::with_capacity(frames.len());
    for f in frames {
        let t0 = Instant::now();
        if from.send_to(f, to).is_err() || receive(at, id).is_err() {
            continue;
        }
        lat.push(t0.elapsed().as_secs_f64() * 1e6);
    }
    lat
}

fn show(what: &str, mut lat: Vec<f64>) {
    lat.sort_by(f64::total_cmp);
    let pct = |p: f64| lat[((lat.len() as f64 * p) as usize).min(lat.len() - 1)];
    println!(
        "{what:<36} n={:>5} p50={:>6.1} µs p99={:>6.1} µs max={:>7.1} µs",
        lat.len(),
        pct(0.50),
        pct(0.99),
        lat[lat.len() - 1]
    );
}

fn socket() -> std::io::Result<UdpSocket> {
    let s = UdpSocket::bind("127.0.0.1:0")?;
    s.set_read_timeout(Some(Duration::from_secs(2)))?;
    Ok(s)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (autopilot, station) = (socket()?, socket()?);
    let toml = format!(
        "connection = \"udpout:127.0.0.1:{}\"\nrate_hz = 1\n[modes]\nset_mode = false\n\
         [[gcs]]\nendpoint = \"udpout:127.0.0.1:{}\"\n",
        autopilot.local_addr()?.port(),
        station.local_addr()?.port()
    );
    let mut settings: MavlinkSettings = toml::from_str(&toml)?;
    let start = Instant::now();
    let now = || MonoTime::ZERO + start.elapsed();
    let mut v = MavlinkVehicle::new(settings.validate()?, now())?;
    // rove's heartbeat tells the autopilot where rove is; the autopilot's first frame through
    // rove tells the station where rove's port for it is.
    let mut buf = [0u8; 512];
    let rove_link = loop {
        let _ = v.keepalive(now());
        if let Ok((_, from)) = autopilot.recv_from(&mut buf) {
            break from;
        }
    };
    let hb = frame(
        1,
        0,
        &MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            mavtype: MavType::MAV_TYPE_GROUND_ROVER,
            autopilot: MavAutopilot::MAV_AUTOPILOT_ARDUPILOTMEGA,
            system_status: MavState::MAV_STATE_ACTIVE,
            ..HEARTBEAT_DATA::default()
        }),
    );
    autopilot.send_to(&hb, rove_link)?;
    let rove_port = receive(&station, 0)?;
    let down: Vec<Vec<u8>> = (0..SAMPLES)
        .map(|i| {
            let attitude = ATTITUDE_DATA {
                time_boot_ms: i as u32,
                ..ATTITUDE_DATA::default()
            };
            frame(1, i as u8, &MavMessage::ATTITUDE(attitude))
        })
        .collect();
    let up: Vec<Vec<u8>> = (0..SAMPLES)
        .map(|i| {
            let command = COMMAND_LONG_DATA {
                target_system: 1,
                confirmation: i as u8,
                ..COMMAND_LONG_DATA::default()
            };
            frame(250, i as u8, &MavMessage::COMMAND_LONG(command))
        })
        .collect();
    let (ap_addr, st_addr) = (autopilot.local_addr()?, station.local_addr()?);
    show(
        "autopilot → station, direct",
        time(&autopilot, st_addr, &station, ATTITUDE, &down),
    );
    show(
        "autopilot → station, through rove",
        time(&autopilot, rove_link, &station, ATTITUDE, &down),
    );
    show(
        "station → autopilot, direct",
        time(&station, ap_addr, &autopilot, COMMAND_LONG, &up),
    );
    show(
        "station → autopilot, through rove",
        time(&station, rove_port, &autopilot, COMMAND_LONG, &up),
    );
    let stations = v.stations();
    println!("rove's port for the station: {stations:?}");
    Ok(())
}
