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

/// Starts operator `id` (a stationary desktop driving `drive`) whose `[input]` is a `ros2`
/// source on the test's ROS domain with `input` as its other keys and tables.
fn ros2_operator(rig: &mut Rig, id: i64, drive: &[i64], input: &str) {
    let drive: Vec<String> = drive.iter().map(i64::to_string).collect();
    let config = rig.write(
        &format!("operator-{id}.toml"),
        &format!(
            "[device]\nid = {id}\nname = \"op{id}\"\n[operator]\nlevel = \"stationary\"\n\
             device_class = \"desktop\"\ndrive = [{}]\n[input]\nsource = \"ros2\"\n\
             domain_id = {ROS_DOMAIN}\n{input}",
            drive.join(", ")
        ),
    );
    let path = config.to_str().expect("utf-8 path");
    rig.spawn(
        &format!("operator-{id}"),
        &["operator", "-c", path, "--headless"],
    );
}

/// Kills process `owner` (`kill -9`) and waits for the robot's zero twist and e-stop after
/// it; returns how long each took, ms.
fn crash_until_stopped(rig: &mut Rig, robot: &RosPeer, owner: usize) -> (f64, f64) {
    let crash = wall_us();
    rig.procs[owner].crash();
    let zero = robot.wait_for("a zero twist after the owner's crash", |l| {
        l["kind"] == "twist" && l["wall_us"].as_u64() > Some(crash) && linear_x(l) == 0.0
    });
    let estop = robot.wait_for("the e-stop after the owner's crash", |l| {
        l["kind"] == "estop" && l["data"] == true && l["wall_us"].as_u64() > Some(crash)
    });
    let ms =
        |l: &Value| l["wall_us"].as_u64().unwrap_or(crash).saturating_sub(crash) as f64 / 1000.0;
    (ms(&zero), ms(&estop))
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

    let (zero, estop) = crash_until_stopped(&mut rig, &robot, laptop);
    eprintln!("crash → zero twist {zero:.1} ms, e-stop {estop:.1} ms");
    // The command timeout is 100 ms; a loaded 2-core machine gets room (the bench measures).
    assert!(zero < 2_000.0 && estop < 2_000.0, "{zero} {estop} ms");

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
    let mode = RosPeer::start(&rig, "mode", &["--owner", "/base/mode"]);
    let output = ros2_output(
        "message = \"Twist\"\ntopic = \"/base/cmd_vel\"\nbattery_topic = \"/base/battery\"\n\
         mode_topic = \"/base/mode\"\n",
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
    // The owner's mode (the laptop asks MANUAL) on the latched mode topic.
    mode.wait_for("the mode on /base/mode", |l| {
        l["kind"] == "owner" && l["data"] == "manual"
    });
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
    let axes = "[input.axes.throttle]\nabs = \"ABS_Y\"\n[input.axes.roll]\nabs = \"ABS_X\"\n";
    ros2_operator(&mut rig, JOY, &[V], &format!("topic = \"/joy\"\n{axes}"));
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

/// A `teleop_twist_keyboard`-style node (an rclpy Twist publisher) drives a rove vehicle
/// through a rove operator with `source = "ros2"`, `message = "Twist"`: linear.x as a
/// fraction of `max_linear` is the throttle.
#[test]
fn a_ros_2_twist_teleop_node_drives_through_a_rove_operator() {
    const TELEOP: i64 = 14;
    let mut rig = Rig::new("ros2-teleop");
    let record = rig.vehicle(V);
    let input = "message = \"Twist\"\ntopic = \"/teleop\"\nmax_linear = 0.5\n\
                 [input.axes.throttle]\nabs = \"ABS_X\"\n";
    ros2_operator(&mut rig, TELEOP, &[V], input);
    let mut teleop = RosPeer::start(&rig, "teleop", &["--twist-out", "/teleop", "--unstamped"]);
    let start = wall_us();
    teleop.send(&serde_json::json!({"linear": [0.0, 0.0, 0.0], "angular": [0.0, 0.0, 0.0]}));
    wait_for_output(&record, Some(TELEOP), start).expect("the teleop operator drives, stopped");
    teleop.send(&serde_json::json!({"linear": [0.25, 0.0, 0.0], "angular": [0.0, 0.0, 0.0]}));
    let half = i64::from(i16::MAX) / 2;
    eventually("half throttle from the teleop node", || {
        let outs = records(&record);
        match outs.iter().rev().find(|o| o.owner == Some(TELEOP)) {
            Some(o) if o.throttle.is_some_and(|t| (t - half).abs() < half / 10) => Ok(()),
            last => Err(format!("{last:?}")),
        }
    });
}

/// A vehicle that stops (SIGTERM, as systemd stops it) leaves its ROS 2 robot at zero with the
/// e-stop set; `rove failsafe` (the unit's `ExecStopPost`, a process of its own) does the same
/// and says it reached the robot.
#[test]
fn a_stop_and_rove_failsafe_leave_the_ros_2_robot_stopped() {
    let mut rig = Rig::new("ros2-stop");
    let robot = RosPeer::start(
        &rig,
        "robot",
        &["--twist", "/cmd_vel", "--stamped", "--estop", "/rove/estop"],
    );
    rig.vehicle_with_output(V, &ros2_output(""));
    rig.operator(
        LAPTOP,
        "stationary",
        "laptop",
        &[V],
        16_384,
        "",
        &["--headless"],
    );
    robot.wait_for("driven", |l| l["kind"] == "twist" && linear_x(l) > 0.0);
    robot.wait_for("the e-stop cleared", |l| {
        l["kind"] == "estop" && l["data"] == false
    });
    let stop = wall_us();
    rig.procs[0].stop();
    robot.wait_for("zero after the vehicle's stop", |l| {
        l["kind"] == "twist" && l["wall_us"].as_u64() > Some(stop) && linear_x(l) == 0.0
    });
    robot.wait_for("the e-stop after the vehicle's stop", |l| {
        l["kind"] == "estop" && l["data"] == true && l["wall_us"].as_u64() > Some(stop)
    });
    let config = rig.dir.join(format!("vehicle-{V}.toml"));
    let before = robot.of("twist").len();
    let out = rig
        .command(&["failsafe", "-c", config.to_str().expect("utf-8 path")])
        .output()
        .expect("run rove failsafe");
    let said = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{said}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(said.contains("acknowledged by 1 subscriber"), "{said}");
    let after = robot.of("twist");
    assert!(after.len() > before, "rove failsafe published no twist");
    assert!(
        after[before..].iter().all(|l| linear_x(l) == 0.0),
        "{after:?}"
    );
}

/// p50 and p99 of `ms`, sorted in place.
fn percentiles(ms: &mut [f64]) -> (f64, f64) {
    ms.sort_by(f64::total_cmp);
    let at = |q: f64| ms[((ms.len() - 1) as f64 * q).round() as usize];
    (at(0.5), at(0.99))
}

/// The figures, in one run (`cargo test -p rove-gateway --test e2e -- --ignored
/// ros2::bench --nocapture`): a Joy node's stick steps through a `ros2` operator to a sim
/// vehicle's output and to an rclpy subscriber of a `ros2` vehicle, p50/p99; then 20 owner
/// crashes, each timed to the zero twist and the e-stop. Timing is reported, not asserted
/// (a benchmark, not a test: it runs by hand).
#[test]
#[ignore = "a benchmark: run by hand with --ignored --nocapture"]
fn bench_joy_and_crash_latencies() {
    const JOY: i64 = 13;
    const SIM: i64 = 101;
    let mut rig = Rig::new("ros2-bench");
    let robot = RosPeer::start(&rig, "robot", &["--twist", "/cmd_vel", "--stamped"]);
    rig.vehicle_with_output(V, &ros2_output(""));
    let sim = rig.vehicle(SIM);
    ros2_operator(
        &mut rig,
        JOY,
        &[V, SIM],
        "[input.axes.throttle]\nabs = \"ABS_Y\"\n",
    );
    let mut joy = RosPeer::start(&rig, "joy", &["--joy", "/joy", "--joy-rate", "2"]);
    let start = wall_us();
    joy.send(&serde_json::json!({"axes": [0.0, 0.0]}));
    wait_for_output(&sim, Some(JOY), start).expect("the Joy operator drives");
    robot.wait_for("a centred twist", |l| l["kind"] == "twist");
    let (mut to_sim, mut to_ros) = (Vec::new(), Vec::new());
    for k in 0..100 {
        let value = 0.3 + 0.004 * f64::from(k);
        let sent = wall_us();
        joy.send(&serde_json::json!({"axes": [0.0, value]}));
        let out = joy.wait_for("the step published", |l| {
            l["kind"] == "joy_out"
                && l["axes"][1]
                    .as_f64()
                    .is_some_and(|a| (a - value).abs() < 1e-4)
        });
        let at = out["wall_us"].as_u64().unwrap_or(sent);
        let applied = eventually("the step at the sim vehicle", || {
            let outs = records(&sim);
            let hit = outs.iter().find(|o| {
                o.wall_us >= at
                    && o.owner == Some(JOY)
                    && o.throttle
                        .is_some_and(|t| t as f64 >= (value - 0.002) * 32_767.0)
            });
            hit.map(|o| o.wall_us).ok_or("not yet")
        });
        let heard = robot.wait_for("the step at the rclpy subscriber", |l| {
            l["kind"] == "twist"
                && l["wall_us"].as_u64() >= Some(at)
                && linear_x(l) >= (value - 0.002) * 0.8
        });
        to_sim.push((applied - at) as f64 / 1000.0);
        to_ros.push((heard["wall_us"].as_u64().unwrap_or(at) - at) as f64 / 1000.0);
    }
    let (sim50, sim99) = percentiles(&mut to_sim);
    let (ros50, ros99) = percentiles(&mut to_ros);
    println!(
        "Joy (rclpy) → ros2 operator → sim vehicle output: p50 {sim50:.2} ms, p99 {sim99:.2} ms (100 steps)"
    );
    println!(
        "Joy (rclpy) → ros2 operator → ros2 vehicle → rclpy TwistStamped: p50 {ros50:.2} ms, p99 {ros99:.2} ms"
    );
    drop(joy);

    // 20 owner crashes on the ROS 2 robot.
    let mut crash_rig = Rig::new("ros2-bench-crash");
    let robot = RosPeer::start(
        &crash_rig,
        "robot",
        &["--twist", "/cmd_vel", "--stamped", "--estop", "/rove/estop"],
    );
    crash_rig.vehicle_with_output(V, &ros2_output(""));
    let (mut zero, mut estop) = (Vec::new(), Vec::new());
    for _ in 0..20 {
        let started = wall_us();
        let laptop = crash_rig.operator(
            LAPTOP,
            "stationary",
            "laptop",
            &[V],
            16_384,
            "",
            &["--headless"],
        );
        robot.wait_for("driven", |l| {
            l["kind"] == "twist" && l["wall_us"].as_u64() > Some(started) && linear_x(l) > 0.0
        });
        robot.wait_for("the e-stop cleared", |l| {
            l["kind"] == "estop" && l["data"] == false && l["wall_us"].as_u64() > Some(started)
        });
        let (z, e) = crash_until_stopped(&mut crash_rig, &robot, laptop);
        zero.push(z);
        estop.push(e);
    }
    let worst = |v: &[f64]| v.iter().copied().fold(0.0, f64::max);
    let (zw, ew) = (worst(&zero), worst(&estop));
    let (z50, z99) = percentiles(&mut zero);
    let (e50, e99) = percentiles(&mut estop);
    println!(
        "owner kill -9 → zero twist: p50 {z50:.1} ms, p99 {z99:.1} ms, max {zw:.1} ms (20 runs, command timeout 100 ms)"
    );
    println!("owner kill -9 → e-stop true: p50 {e50:.1} ms, p99 {e99:.1} ms, max {ew:.1} ms");
}
