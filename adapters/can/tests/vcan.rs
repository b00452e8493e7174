//! End to end on a virtual CAN interface: the vehicle sends through [`SocketCanBus`] and a
//! second socket on the same interface reads the frames back.
//!
//! Needs `vcan0`, which needs a kernel with `CONFIG_CAN_VCAN`:
//!
//! ```text
//! sudo modprobe vcan
//! sudo ip link add vcan0 type vcan
//! sudo ip link set up vcan0
//! cargo test -p rove-can --test vcan -- --nocapture
//! ```
//!
//! The two tests that need `vcan0` are ignored by default (`cargo test` lists them as ignored,
//! with the reason) and fail, saying why, when run without it. `scripts/test` creates `vcan0`
//! where the kernel has the module and then runs them with `--ignored`; where it cannot, its
//! final line counts them as skipped.

#![cfg(feature = "socketcan")]

use rove_can::{CanBus, CanSettings, CanVehicle, SocketCanBus};
use rove_core::MonoTime;
use rove_core::adapter::OutputAdapter;
use rove_core::arbiter::Setpoint;
use rove_core::msg::{Mode, MovementCommand};
use socketcan::{CanFrame, CanSocket, EmbeddedFrame, Socket};
use std::time::{Duration, Instant};

const INTERFACE: &str = "vcan0";

/// How long to wait for frames that a local virtual interface delivers at once.
const READ_DEADLINE: Duration = Duration::from_secs(2);

/// The receiving socket; without `vcan0` the test fails with how to make one.
fn receiver() -> CanSocket {
    let missing = |why: String| -> ! {
        panic!(
            "cannot open {INTERFACE} ({why}). To run this test: `sudo modprobe vcan; \
             sudo ip link add {INTERFACE} type vcan; sudo ip link set up {INTERFACE}` \
             (scripts/test does it where the kernel has the module)."
        )
    };
    if let Err(e) = SocketCanBus::open(INTERFACE, false) {
        missing(e.detail);
    }
    let socket = CanSocket::open(INTERFACE).unwrap_or_else(|e| missing(e.to_string()));
    if let Err(e) = socket.set_read_timeout(Duration::from_millis(100)) {
        missing(e.to_string());
    }
    socket
}

/// Reads `count` data frames as `(id, bytes)`, or fails after [`READ_DEADLINE`].
fn read_frames(socket: &CanSocket, count: usize) -> Vec<(u32, Vec<u8>)> {
    let deadline = Instant::now() + READ_DEADLINE;
    let mut got = Vec::new();
    while got.len() < count {
        assert!(
            Instant::now() < deadline,
            "only {} of {count} frames arrived: {got:02X?}",
            got.len()
        );
        if let Ok(CanFrame::Data(f)) = socket.read_frame() {
            let id = match f.id() {
                socketcan::Id::Standard(id) => u32::from(id.as_raw()),
                socketcan::Id::Extended(id) => id.as_raw(),
            };
            got.push((id, f.data().to_vec()));
        }
    }
    got
}

fn vehicle(text: &str) -> CanVehicle {
    let config = toml::from_str::<CanSettings>(text)
        .expect("parses")
        .validate()
        .expect("valid");
    let bus = rove_can::open_bus(&config).expect("vcan0 opened above");
    CanVehicle::new(config, bus, MonoTime::ZERO).expect("starts")
}

#[test]
#[ignore = "needs vcan0 (a kernel with CONFIG_CAN_VCAN); scripts/test makes it where it can"]
fn raw_frames_round_trip_on_vcan() {
    let rx = receiver();
    let mut v = vehicle(
        r#"
        interface = "vcan0"
        [[frames]]
        id = 0x100
        [[frames.outputs]]
        source = { mix = [["throttle", 1.0], ["roll", 1.0]] }
        offset = 0
        min = -1000
        max = 1000
        [[frames.outputs]]
        source = { mix = [["throttle", 1.0], ["roll", -1.0]] }
        offset = 2
        endian = "big"
        min = -1000
        max = 1000
        "#,
    );
    // The safe state at start: both motors 0.
    assert_eq!(read_frames(&rx, 1), [(0x100, vec![0, 0, 0, 0])]);
    let setpoint = Setpoint {
        movement: MovementCommand {
            throttle: 16384,
            roll: 8192,
            ..MovementCommand::CENTRED
        },
        mode: Mode::Manual,
    };
    v.apply(MonoTime::from_millis(10), &setpoint).expect("sent");
    // left 750 little-endian, right 250 big-endian.
    assert_eq!(read_frames(&rx, 1), [(0x100, vec![0xEE, 0x02, 0x00, 0xFA])]);
    v.keepalive(MonoTime::from_millis(30)).expect("sent");
    assert_eq!(read_frames(&rx, 1).len(), 1);
}

#[test]
#[ignore = "needs vcan0 (a kernel with CONFIG_CAN_VCAN); scripts/test makes it where it can"]
fn dronecan_transfer_round_trips_on_vcan() {
    let rx = receiver();
    let _v = vehicle(
        r#"
        interface = "vcan0"
        [dronecan]
        node_id = 100
        [[dronecan.servos]]
        actuator_id = 0
        source = "roll"
        failsafe = -1.0
        [[dronecan.servos]]
        actuator_id = 1
        source = "pitch"
        failsafe = 0.25
        "#,
    );
    // ArrayCommand (8 bytes: two frames with the CRC) and NodeStatus, extended ids.
    let frames = read_frames(&rx, 3);
    assert_eq!(frames[0].0, 0x1003_F264);
    assert_eq!(frames[1].0, 0x1003_F264);
    assert_eq!(frames[2].0, 0x1801_5564);
    assert_eq!(&frames[0].1[2..], [0x00, 0x00, 0x00, 0xBC, 0x01, 0x80]);
    assert_eq!(frames[1].1, [0x00, 0x00, 0x34, 0x60]);
}

#[test]
fn a_missing_interface_is_transient() {
    // Runs everywhere: an interface that does not exist is ENODEV, transient (CAN adapters
    // are hot-plugged; the gateway waits in failsafe and retries). A kernel without SocketCAN
    // gives the same ENODEV, since the name is looked up before the socket is created.
    match SocketCanBus::open("rove-nocan9", false) {
        Ok(bus) => panic!("opened a non-existent interface: {}", bus.describe()),
        Err(e) => {
            eprintln!("as expected: {}", e.detail);
            assert_eq!(e.disposition, rove_core::error::Disposition::Transient);
        }
    }
}
