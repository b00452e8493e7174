//! A ROS 2 robot as a rove vehicle (issue 47), against real ROS 2 nodes: rclpy 9 with
//! rmw_fastrtps_cpp (Fast DDS), from PyPI (`scripts/test` installs them into `.venv`), as
//! `testkit/ros2_peer.py`, in the rig's network namespace. The ROS 2 side and the hierarchy
//! share the namespace's loopback, on different DDS domains.

use crate::util::{Rig, eventually, records, wait_for_output, wall_us};
use serde_json::Value;
use std::io::Write as _;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

const V: i64 = 100;
const LAPTOP: i64 = 11;
/// The ROS 2 graph's domain, apart from the hierarchy's (0).
const ROS_DOMAIN: u16 = 7;

/// `testkit/ros2_peer.py ARGS` in the rig's namespace, its JSON lines in a file; killed on
/// drop.
struct RosPeer {
    child: Child,
    out: PathBuf,
}

impl RosPeer {
    fn start(rig: &Rig, name: &str, args: &[&str]) -> RosPeer {
        rove_testkit::require_python_peers();
        let out = rig.dir.join(format!("{name}.jsonl"));
        let file = std::fs::File::create(&out).expect("peer record");
        let domain = ROS_DOMAIN.to_string();
        let child = Command::new("ip")
            .args(["netns", "exec", &rig.ns])
            .arg(rove_testkit::python())
            .arg(rove_testkit::repo_root().join("testkit/ros2_peer.py"))
            .args(["--domain", &domain, "--name", name, "--udp-only"])
            .args(args)
            .stdin(Stdio::piped())
            .stdout(file)
            .stderr(Stdio::inherit())
            .spawn()
            .expect("python runs ros2_peer.py");
        let peer = RosPeer { child, out };
        peer.wait_for("the ROS 2 node ready", |l| l["kind"] == "ready");
        peer
    }

    fn lines(&self) -> Vec<Value> {
        std::fs::read_to_string(&self.out)
            .unwrap_or_default()
            .lines()
            .filter_map(|l| serde_json::from_str(l).ok())
            .collect()
    }

    fn of(&self, kind: &str) -> Vec<Value> {
        (self.lines().into_iter())
            .filter(|l| l["kind"] == kind)
            .collect()
    }

    fn wait_for(&self, what: &str, pred: impl Fn(&Value) -> bool) -> Value {
        eventually(what, || {
            let lines = self.lines();
            match lines.iter().find(|l| pred(l)) {
                Some(l) => Ok(l.clone()),
                None => Err(format!(
                    "{:?}",
                    lines.iter().rev().take(5).collect::<Vec<_>>()
                )),
            }
        })
    }
}

impl RosPeer {
    /// Sends one JSON line to the peer's standard input (its publishers' commands).
    fn send(&mut self, line: &Value) {
        let stdin = self.child.stdin.as_mut().expect("piped stdin");
        writeln!(stdin, "{line}").expect("the peer reads its stdin");
    }
}

impl Drop for RosPeer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn ros2_output(extra: &str) -> String {
    format!(
        "[output]\nadapter = \"ros2\"\ndomain_id = {ROS_DOMAIN}\nrate_hz = 20\nzero_for_ms = 500\n\
         {extra}[[output.twist]]\ncomponent = \"linear.x\"\naxis = \"throttle\"\nmax = 0.8\n\
         [[output.twist]]\ncomponent = \"angular.z\"\naxis = \"roll\"\nmax = 1.5\nreverse = true\n"
    )
}

/// The owner topic's JSON text, read.
fn parsed(line: &Value) -> Value {
    serde_json::from_str(line["data"].as_str().unwrap_or("")).unwrap_or(Value::Null)
}

/// The owner an owner line names (`Value::Null` for the failsafe), if it is one.
fn owner_of(line: &Value) -> Option<Value> {
    parsed(line).get("owner").cloned()
}

fn linear_x(line: &Value) -> f64 {
    line["linear"][0].as_f64().unwrap_or(f64::NAN)
}

/// A laptop's constant sticks reach an rclpy subscriber as TwistStamped at the configured
/// scale; the publish rate while driven is measured; the owner's `kill -9` brings a zero twist
/// and the e-stop within the command timeout (measured, asserted with room for a loaded
/// machine); a late rclpy subscriber of the latched e-stop gets its value.
#[test]
fn a_laptop_drives_a_ros_2_robot_and_its_crash_stops_it() {
    let mut rig = Rig::new("ros2-drive");
    let robot = RosPeer::start(
        &rig,
        "robot",
        &[
            "--twist",
            "/cmd_vel",
            "--stamped",
            "--estop",
            "/rove/estop",
            "--owner",
            "/rove/owner",
            "--diagnostics",
        ],
    );
    rig.vehicle_with_output(V, &ros2_output(""));
    // Nobody drives yet: the vehicle's failsafe publishes zero and sets the e-stop.
    robot.wait_for("the e-stop set at start", |l| {
        l["kind"] == "estop" && l["data"] == true
    });
    let throttle: i16 = 16_384;
    let laptop = rig.operator(
        LAPTOP,
        "stationary",
        "laptop",
        &[V],
        throttle,
        "",
        &["--headless"],
    );
    let driven = robot.wait_for("the laptop's sticks on /cmd_vel", |l| {
        l["kind"] == "twist" && linear_x(l) > 0.0
    });
    let want = 0.8 * f64::from(throttle) / f64::from(i16::MAX);
    assert!((linear_x(&driven) - want).abs() < 1e-6, "{driven}");
    assert_eq!(driven["angular"][2].as_f64(), Some(0.0), "{driven}");
    assert_eq!(driven["frame_id"], "base_link", "{driven}");
    robot.wait_for("the e-stop cleared while driven", |l| {
        l["kind"] == "estop" && l["data"] == false
    });
    // Who drives, latched, and the standing on /diagnostics.
    let owner = robot.wait_for("the laptop named on /rove/owner", |l| {
        l["kind"] == "owner" && owner_of(l) == Some(Value::from(LAPTOP))
    });
    assert_eq!(parsed(&owner)["failsafe"], false, "{owner}");
    let diagnostics = robot.wait_for("the laptop driving on /diagnostics", |l| {
        l["kind"] == "diagnostics"
            && l["status"][0]["message"]
                .as_str()
                .is_some_and(|m| m.starts_with("driven by 11"))
    });
    assert_eq!(diagnostics["status"][0]["level"], 0, "{diagnostics}");
    assert_eq!(
        diagnostics["status"][0]["name"], "rove: vehicle 100",
        "{diagnostics}"
    );
    // The rate while driven: the laptop streams at 50 Hz, the adapter publishes at least 20.
    let window = Duration::from_secs(2);
    let before = robot.of("twist").len();
    std::thread::sleep(window);
    let rate = (robot.of("twist").len() - before) as f64 / window.as_secs_f64();
    eprintln!("driven: {rate:.1} twists/s");
    assert!(rate >= 20.0 * 0.5, "{rate} twists/s while driven");

    let crash = wall_us();
    rig.procs[laptop].crash();
    let zero = robot.wait_for("a zero twist after the owner's crash", |l| {
        l["kind"] == "twist" && l["wall_us"].as_u64() > Some(crash) && linear_x(l) == 0.0
    });
    let estop = robot.wait_for("the e-stop after the owner's crash", |l| {
        l["kind"] == "estop" && l["data"] == true && l["wall_us"].as_u64() > Some(crash)
    });
    let ms = |l: &Value| {
        l["wall_us"]
            .as_u64()
            .unwrap_or(u64::MAX)
            .saturating_sub(crash)
            / 1000
    };
    eprintln!(
        "crash → zero twist {} ms, e-stop {} ms",
        ms(&zero),
        ms(&estop)
    );
    // The command timeout is 100 ms; a loaded 2-core machine gets room (the bench measures).
    assert!(ms(&zero) < 2_000 && ms(&estop) < 2_000, "{zero} {estop}");

    // A subscriber that joins late gets the latched e-stop at once.
    let late = RosPeer::start(&rig, "late", &["--estop", "/rove/estop"]);
    late.wait_for("the latched e-stop", |l| {
        l["kind"] == "estop" && l["data"] == true
    });
}

/// `message = "Twist"`: an rclpy `Twist` subscriber matches; rclpy's graph lists rove's topics
/// with their ROS 2 types; a `sensor_msgs/BatteryState` at 20 % shows as a low battery in
/// `rove status --json`.
#[test]
fn a_twist_robot_sees_rove_in_its_graph_and_its_battery_reaches_rove_status() {
    let mut rig = Rig::new("ros2-twist");
    let robot = RosPeer::start(
        &rig,
        "robot",
        &["--twist", "/base/cmd_vel", "--unstamped", "--graph"],
    );
    let _battery = RosPeer::start(
        &rig,
        "battery",
        &["--battery", "/base/battery", "--percentage", "0.2"],
    );
    let output = ros2_output(
        "message = \"Twist\"\ntopic = \"/base/cmd_vel\"\nbattery_topic = \"/base/battery\"\n",
    );
    rig.vehicle_with_output(V, &output);
    rig.operator(
        LAPTOP,
        "stationary",
        "laptop",
        &[V],
        8_000,
        "",
        &["--headless"],
    );
    robot.wait_for("a Twist with the laptop's sticks", |l| {
        l["kind"] == "twist" && linear_x(l) > 0.0
    });
    let graph = robot.wait_for("rove's topics in the ROS 2 graph", |l| {
        let topics = l["topics"].to_string();
        l["kind"] == "graph"
            && topics.contains("[\"/base/cmd_vel\",[\"geometry_msgs/msg/Twist\"]]")
            && topics.contains("[\"/rove/estop\",[\"std_msgs/msg/Bool\"]]")
    });
    eprintln!("{graph}");
    let row = rig.device_when("the robot's battery low in rove status", V, |d| {
        d["health"]["battery_low"] == true
    });
    assert_eq!(row["health"]["battery_pct"], 20, "{row}");
}

/// An rclpy `sensor_msgs/Joy` publisher (as the `joy` node) drives a rove vehicle through a
/// rove operator with `[input] source = "ros2"`; a phone preempts it, and when the phone quits
/// the Joy operator drives again; when the Joy messages stop, the operator lets go and the
/// vehicle's failsafe takes over.
#[test]
fn a_ros_2_joy_node_drives_through_a_rove_operator_and_a_phone_preempts_it() {
    const JOY: i64 = 13;
    const PHONE: i64 = 12;
    let mut rig = Rig::new("ros2-joy");
    let record = rig.vehicle(V);
    let config = rig.write(
        "operator-joy.toml",
        &format!(
            "[device]\nid = {JOY}\nname = \"joy\"\n[operator]\nlevel = \"stationary\"\n\
             device_class = \"desktop\"\ndrive = [{V}]\n[input]\nsource = \"ros2\"\n\
             topic = \"/joy\"\ndomain_id = {ROS_DOMAIN}\n\
             [input.axes.throttle]\nabs = \"ABS_Y\"\n[input.axes.roll]\nabs = \"ABS_X\"\n"
        ),
    );
    let path = config.to_str().expect("utf-8 path");
    rig.spawn("operator-13", &["operator", "-c", path, "--headless"]);
    let mut joy = RosPeer::start(&rig, "joy", &["--joy", "/joy"]);
    // Centred first (the no-jump rule): the operator drives with centred sticks once it hears
    // the node; then half forward.
    let start = wall_us();
    joy.send(&serde_json::json!({"axes": [0.0, 0.0], "buttons": [0, 0]}));
    wait_for_output(&record, Some(JOY), start).expect("the Joy operator drives, centred");
    joy.send(&serde_json::json!({"axes": [0.0, 0.5], "buttons": [0, 0]}));
    let half = i64::from(i16::MAX) / 2;
    let driven = eventually("half throttle from the Joy operator", || {
        let outs = records(&record);
        match outs.iter().rev().find(|o| o.owner == Some(JOY)) {
            Some(o) if o.throttle.is_some_and(|t| (t - half).abs() < half / 10) => Ok(o.clone()),
            last => Err(format!("{last:?}")),
        }
    });
    eprintln!("{driven:?}");
    let joined = wall_us();
    let phone = rig.operator(PHONE, "mobile", "phone", &[V], 3_000, "", &["--headless"]);
    wait_for_output(&record, Some(PHONE), joined).expect("the phone preempts the Joy operator");
    let quit = wall_us();
    rig.procs[phone].terminate();
    wait_for_output(&record, Some(JOY), quit).expect("the Joy operator drives again");
    let stopped = wall_us();
    joy.send(&serde_json::json!({"stop": true}));
    wait_for_output(&record, None, stopped).expect("failsafe once the Joy messages stop");
}
