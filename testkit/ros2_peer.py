#!/usr/bin/env python3
"""A real ROS 2 node (rclpy, rmw_fastrtps_cpp) for rove's ROS 2 tests: the robot software on
the other side of rove's ROS 2 bridge, as a ROS user would run it (docs/ros2.md, "ROS 2 from
rove's side").

    ros2_peer.py [--options]   (run inside the test's network namespace: lo up, multicast on,
                                224.0.0.0/4 routed to lo; never on a shared network)

All options combine in one process (one node, one participant):

Subscriptions (each sample is printed as it is received):
  --twist TOPIC         geometry_msgs/TwistStamped (--stamped, the default) or Twist
                        (--unstamped); reliable, volatile, keep last 10 (rclpy's defaults).
                        {"kind":"twist","t":T,"topic":..,"linear":[x,y,z],"angular":[x,y,z],
                         "stamp":[sec,nanosec],"frame_id":".."}  (stamp, frame_id null unstamped)
  --estop TOPIC         std_msgs/Bool, reliable + transient local, keep last 1 (latched):
                        {"kind":"estop","t":T,"topic":..,"data":true}
  --owner TOPIC         std_msgs/String, reliable + transient local, keep last 1 (latched):
                        {"kind":"owner","t":T,"topic":..,"data":".."}
  --diagnostics [TOPIC] diagnostic_msgs/DiagnosticArray on /diagnostics (or TOPIC); reliable,
                        volatile, keep last 10:
                        {"kind":"diagnostics","t":T,"topic":..,"stamp":[s,ns],"status":[
                          {"name":..,"level":L,"message":..,"hardware_id":..,
                           "values":[[key,value],...]}, ...]}
  Each subscription and publisher also reports its matches and QoS conflicts (side "sub" or
  "pub"), as Fast DDS sees them: a writer matched here may not be known to the remote reader yet
  (a Cyclone DDS reader started at the same time took up to 4 s more; wait for data, not for
  this line, where it matters):
    {"kind":"matched","t":T,"topic":..,"side":"sub","count":N,"change":+1/-1}
    {"kind":"incompatible_qos","t":T,"topic":..,"side":"sub","policy":"DURABILITY","count":N}

Publishers:
  --battery TOPIC --percentage P [--voltage V] [--rate HZ]
                        sensor_msgs/BatteryState at HZ (default 2): percentage P (0..1, as ROS
                        defines it; NaN if unknown), voltage V (default 12.0), present, the
                        other measurements NaN (ROS's "unmeasured").
  --joy TOPIC           sensor_msgs/Joy from standard input: each line {"axes":[..],
                        "buttons":[..]} is published at once and then again at --joy-rate HZ
                        (default 20) until the next line.
  --twist-out TOPIC     geometry_msgs/TwistStamped (--stamped) or Twist (--unstamped) from
                        standard input: lines {"linear":[x,y,z],"angular":[x,y,z]}, published
                        like --joy's.
  Input lines go to the publisher their keys name (axes/buttons: --joy; linear/angular:
  --twist-out). A line `stop` (or "stop", or {"stop":true}) stops both publishing; {"stop":"joy"}
  or {"stop":"twist"} one. Each line's first publication is printed:
    {"kind":"joy_out","t":T,"topic":..,"axes":[..],"buttons":[..]}
    {"kind":"twist_out","t":T,"topic":..,"linear":[..],"angular":[..]}
    {"kind":"stopped","t":T,"which":["joy",...]}
  A line that cannot be read: {"kind":"bad_input","t":T,"line":".."}. Stamps are the node's
  clock (wall time); --frame-id sets header.frame_id of Joy and TwistStamped.

Other:
  --graph               every 0.5 s: {"kind":"graph","t":T,"topics":[[name,[types...]],...]}
                        from node.get_topic_names_and_types().
  --domain N            the ROS domain id (default: $ROS_DOMAIN_ID, else 0).
  --name NAME           the node's name (default ros2_peer).
  --udp-only            Fast DDS's UDPv4 transport alone (FASTDDS_BUILTIN_TRANSPORTS=UDPv4): two
                        rclpy peers then talk over UDP as rove does, not through shared memory,
                        and a peer killed with SIGKILL leaves no segments in /dev/shm. (With or
                        without it, Fast DDS speaks UDP to rove: rove offers no shared memory.)
  --no-type-info        no XTypes type information in discovery (Fast DDS property
                        fastdds.type_propagation = disabled, through a profile file named in
                        FASTDDS_DEFAULT_PROFILES_FILE): needed beside a Cyclone DDS peer for
                        types with sequences (BatteryState, Joy, DiagnosticArray), whose Fast DDS
                        type objects Cyclone rejects, so it never matches them. rustdds (rove)
                        ignores type information and needs neither.
  --duration S          exit after S seconds (default 600: bounded).
  --keep-on-eof         end of standard input stops the publishers but not the process (for a
                        subscriber started without standard input).

Each line also has "wall_us", the wall clock in µs (what rove's records and the tests' own
timestamps use). T is time.monotonic() in seconds, taken when the sample is
taken from the node's queue (received) or just before it is published (sent). The first line is
{"kind":"ready","t":T,"pid":P,"domain":N,"name":NAME} once the node spins, its topics made
(lines made before it, such as a match found at once, follow it with their own T). One JSON
object per line on standard output, flushed at once; rclpy's own log lines go to standard error
(no log files, no /rosout).

Exits 0 on SIGTERM, SIGINT, end of standard input (unless --keep-on-eof) or --duration, with a
last line {"kind":"exit","t":T,"reason":"sigterm"|"eof"|"duration",
"received":{kind:N},"sent":{topic:N}}.
"""

import argparse
import json
import os
import signal
import sys
import tempfile
import threading
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.signals import SignalHandlerOptions

from geometry_msgs.msg import Twist, TwistStamped
from sensor_msgs.msg import BatteryState, Joy
from std_msgs.msg import Bool, String

try:
    from diagnostic_msgs.msg import DiagnosticArray
except ImportError:  # ros-diagnostic-msgs not installed
    DiagnosticArray = None

NO_TYPE_INFO_XML = """<?xml version="1.0" encoding="UTF-8" ?>
<dds xmlns="http://www.eprosima.com">
  <profiles>
    <participant profile_name="ros2_peer_no_type_info" is_default_profile="true">
      <rtps>
        <propertiesPolicy>
          <properties>
            <property><name>fastdds.type_propagation</name><value>disabled</value></property>
          </properties>
        </propertiesPolicy>
      </rtps>
    </participant>
  </profiles>
</dds>
"""

_out_lock = threading.Lock()
_held = []  # lines made before "ready" (a match or a QoS conflict found at once), printed after it


def emit(kind, **fields):
    global _held
    line = {"kind": kind, "t": time.monotonic(), "wall_us": time.time_ns() // 1000}
    line.update(fields)
    with _out_lock:
        if _held is not None and kind != "ready":
            _held.append(line)
            return
        sys.stdout.write(json.dumps(line) + "\n")
        if kind == "ready":
            for held in _held:
                sys.stdout.write(json.dumps(held) + "\n")
            _held = None
        sys.stdout.flush()


def vec(v):
    return [v.x, v.y, v.z]


def set_vec(v, xyz, what):
    xyz = list(xyz) if xyz is not None else [0.0, 0.0, 0.0]
    if len(xyz) != 3:
        raise ValueError("%s needs 3 numbers" % what)
    v.x, v.y, v.z = (float(c) for c in xyz)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--twist", metavar="TOPIC")
    p.add_argument("--twist-out", metavar="TOPIC")
    stamped = p.add_mutually_exclusive_group()
    stamped.add_argument("--stamped", dest="stamped", action="store_true", default=True,
                         help="TwistStamped for --twist and --twist-out (the default)")
    stamped.add_argument("--unstamped", dest="stamped", action="store_false",
                         help="Twist for --twist and --twist-out")
    p.add_argument("--estop", metavar="TOPIC")
    p.add_argument("--owner", metavar="TOPIC")
    p.add_argument("--diagnostics", metavar="TOPIC", nargs="?", const="/diagnostics")
    p.add_argument("--battery", metavar="TOPIC")
    p.add_argument("--percentage", type=float, default=float("nan"),
                   help="BatteryState.percentage, 0..1")
    p.add_argument("--voltage", type=float, default=12.0)
    p.add_argument("--rate", type=float, default=2.0, help="--battery's rate, Hz")
    p.add_argument("--joy", metavar="TOPIC")
    p.add_argument("--joy-rate", type=float, default=20.0,
                   help="repeat rate of --joy and --twist-out, Hz")
    p.add_argument("--frame-id", default="")
    p.add_argument("--graph", action="store_true")
    p.add_argument("--domain", type=int, default=int(os.environ.get("ROS_DOMAIN_ID", "0") or 0))
    p.add_argument("--name", default="ros2_peer")
    p.add_argument("--duration", type=float, default=600.0)
    p.add_argument("--keep-on-eof", action="store_true")
    p.add_argument("--udp-only", action="store_true")
    p.add_argument("--no-type-info", action="store_true")
    a = p.parse_args()
    if a.diagnostics and DiagnosticArray is None:
        p.error("--diagnostics needs diagnostic_msgs (pip install ros-diagnostic-msgs)")
    if a.battery and not (a.rate > 0):
        p.error("--rate must be > 0")
    if (a.joy or a.twist_out) and not (a.joy_rate > 0):
        p.error("--joy-rate must be > 0")

    # Fast DDS reads these when the participant is made (rclpy.init), not at import.
    profiles = None
    if a.udp_only:
        os.environ["FASTDDS_BUILTIN_TRANSPORTS"] = "UDPv4"
    if a.no_type_info:
        if os.environ.get("FASTDDS_DEFAULT_PROFILES_FILE"):
            p.error("--no-type-info: FASTDDS_DEFAULT_PROFILES_FILE is set already")
        fd, profiles = tempfile.mkstemp(prefix="ros2_peer-", suffix=".xml")
        with os.fdopen(fd, "w") as f:
            f.write(NO_TYPE_INFO_XML)
        os.environ["FASTDDS_DEFAULT_PROFILES_FILE"] = profiles

    # Our own signal handling (rclpy's would raise out of spin); no log files, no /rosout.
    ctx_args = ["--ros-args", "--disable-external-lib-logs", "--disable-rosout-logs"]
    rclpy.init(args=ctx_args, domain_id=a.domain,
               signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(a.name)
    executor = SingleThreadedExecutor()
    executor.add_node(node)

    stop = {"reason": None}
    received = {}
    sent = {}
    pub_lock = threading.Lock()  # the stdin thread and the executor's timers both publish

    def on_signal(signum, _frame):
        stop["reason"] = "sigterm" if signum == signal.SIGTERM else "sigint"

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)

    def count(kind):
        received[kind] = received.get(kind, 0) + 1

    def events(topic, side="sub"):
        def matched(info):
            if info.current_count_change:  # (a last event with change 0 comes at shutdown)
                emit("matched", topic=topic, side=side, count=info.current_count,
                     change=info.current_count_change)

        def incompatible(info):
            emit("incompatible_qos", topic=topic, side=side, count=info.total_count,
                 policy=info.last_policy_kind.name.replace("RMW_QOS_POLICY_", ""))

        if side == "pub":
            return PublisherEventCallbacks(matched=matched, incompatible_qos=incompatible)
        return SubscriptionEventCallbacks(matched=matched, incompatible_qos=incompatible)

    reliable_10 = QoSProfile(depth=10, history=HistoryPolicy.KEEP_LAST,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE)
    latched = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    twist_type = TwistStamped if a.stamped else Twist
    subs = []

    if a.twist:
        topic = a.twist

        def on_twist(m):
            count("twist")
            if a.stamped:
                t, frame = m.twist, m.header.frame_id
                stamp = [m.header.stamp.sec, m.header.stamp.nanosec]
            else:
                t, stamp, frame = m, None, None
            emit("twist", topic=topic, linear=vec(t.linear), angular=vec(t.angular),
                 stamp=stamp, frame_id=frame)

        subs.append(node.create_subscription(twist_type, topic, on_twist, reliable_10,
                                             event_callbacks=events(topic)))
    if a.estop:
        topic_e = a.estop

        def on_estop(m):
            count("estop")
            emit("estop", topic=topic_e, data=bool(m.data))

        subs.append(node.create_subscription(Bool, topic_e, on_estop, latched,
                                             event_callbacks=events(topic_e)))
    if a.owner:
        topic_o = a.owner

        def on_owner(m):
            count("owner")
            emit("owner", topic=topic_o, data=m.data)

        subs.append(node.create_subscription(String, topic_o, on_owner, latched,
                                             event_callbacks=events(topic_o)))
    if a.diagnostics:
        topic_d = a.diagnostics

        def on_diag(m):
            count("diagnostics")
            emit("diagnostics", topic=topic_d, stamp=[m.header.stamp.sec, m.header.stamp.nanosec],
                 status=[{"name": s.name,
                          "level": s.level[0] if isinstance(s.level, bytes) else int(s.level),
                          "message": s.message, "hardware_id": s.hardware_id,
                          "values": [[kv.key, kv.value] for kv in s.values]}
                         for s in m.status])

        subs.append(node.create_subscription(DiagnosticArray, topic_d, on_diag, reliable_10,
                                             event_callbacks=events(topic_d)))

    if a.battery:
        battery_pub = node.create_publisher(BatteryState, a.battery, reliable_10,
                                          event_callbacks=events(a.battery, "pub"))

        def send_battery():
            m = BatteryState()
            m.header.stamp = node.get_clock().now().to_msg()
            m.header.frame_id = a.frame_id
            nan = float("nan")
            m.voltage = a.voltage
            m.temperature = m.current = m.charge = m.capacity = m.design_capacity = nan
            m.percentage = a.percentage
            m.power_supply_status = BatteryState.POWER_SUPPLY_STATUS_DISCHARGING
            m.power_supply_health = BatteryState.POWER_SUPPLY_HEALTH_UNKNOWN
            m.power_supply_technology = BatteryState.POWER_SUPPLY_TECHNOLOGY_UNKNOWN
            m.present = True
            with pub_lock:
                battery_pub.publish(m)
            sent[a.battery] = sent.get(a.battery, 0) + 1

        node.create_timer(1.0 / a.rate, send_battery)

    # Streams driven by standard input: the last command of each, repeated until changed.
    streams = {}

    def stream_send(name):
        s = streams[name]
        msg = s["make"](s["cmd"])
        with pub_lock:
            s["pub"].publish(msg)
        sent[s["topic"]] = sent.get(s["topic"], 0) + 1

    if a.joy:
        joy_pub = node.create_publisher(Joy, a.joy, reliable_10,
                                        event_callbacks=events(a.joy, "pub"))

        def make_joy(cmd):
            m = Joy()
            m.header.stamp = node.get_clock().now().to_msg()
            m.header.frame_id = a.frame_id
            m.axes = [float(x) for x in cmd.get("axes", [])]
            m.buttons = [int(b) for b in cmd.get("buttons", [])]
            return m

        streams["joy"] = {"pub": joy_pub, "topic": a.joy, "make": make_joy, "cmd": None}
    if a.twist_out:
        twist_pub = node.create_publisher(twist_type, a.twist_out, reliable_10,
                                          event_callbacks=events(a.twist_out, "pub"))

        def make_twist(cmd):
            if a.stamped:
                m = TwistStamped()
                m.header.stamp = node.get_clock().now().to_msg()
                m.header.frame_id = a.frame_id
                t = m.twist
            else:
                m = t = Twist()
            set_vec(t.linear, cmd.get("linear"), "linear")
            set_vec(t.angular, cmd.get("angular"), "angular")
            return m

        streams["twist"] = {"pub": twist_pub, "topic": a.twist_out, "make": make_twist,
                            "cmd": None}

    def repeat():
        with stream_lock:
            for name, s in streams.items():
                if s["cmd"] is not None:
                    stream_send(name)

    stream_lock = threading.Lock()
    if streams:
        node.create_timer(1.0 / a.joy_rate, repeat)

    def handle_line(line):
        line = line.strip()
        if not line:
            return
        try:
            cmd = json.loads(line)
        except ValueError:
            cmd = line
        with stream_lock:
            if cmd == "stop" or (isinstance(cmd, dict) and "stop" in cmd):
                which = cmd.get("stop") if isinstance(cmd, dict) else True
                names = [n for n in streams if which is True or which == n]
                for n in names:
                    streams[n]["cmd"] = None
                emit("stopped", which=names)
                return
            keys = set(cmd) if isinstance(cmd, dict) else set()
            if keys & {"axes", "buttons"} and "joy" in streams:
                name, kind = "joy", "joy_out"
            elif keys & {"linear", "angular"} and "twist" in streams:
                name, kind = "twist", "twist_out"
            else:
                emit("bad_input", line=line)
                return
            try:
                streams[name]["make"](cmd)  # validate before it replaces the last command
            except (TypeError, ValueError) as e:
                emit("bad_input", line=line, error=str(e))
                return
            streams[name]["cmd"] = cmd
            if name == "joy":
                emit(kind, topic=a.joy, axes=[float(x) for x in cmd.get("axes", [])],
                     buttons=[int(b) for b in cmd.get("buttons", [])])
            else:
                emit(kind, topic=a.twist_out,
                     linear=[float(x) for x in cmd.get("linear") or [0, 0, 0]],
                     angular=[float(x) for x in cmd.get("angular") or [0, 0, 0]])
            stream_send(name)

    def read_stdin():
        try:
            for line in sys.stdin:
                handle_line(line)
        except (OSError, ValueError):
            pass
        with stream_lock:
            for s in streams.values():
                s["cmd"] = None
        if not a.keep_on_eof and stop["reason"] is None:
            stop["reason"] = "eof"

    if a.graph:
        def graph():
            topics = node.get_topic_names_and_types()
            emit("graph", topics=[[name, list(types)] for name, types in topics])

        node.create_timer(0.5, graph)

    def ready():
        ready_timer.cancel()
        emit("ready", pid=os.getpid(), domain=a.domain, name=a.name)
        threading.Thread(target=read_stdin, daemon=True).start()

    ready_timer = node.create_timer(0.0, ready)

    deadline = time.monotonic() + a.duration
    try:
        while stop["reason"] is None:
            if time.monotonic() >= deadline:
                stop["reason"] = "duration"
                break
            executor.spin_once(timeout_sec=0.05)
    finally:
        with stream_lock:
            for s in streams.values():
                s["cmd"] = None
        emit("exit", reason=stop["reason"], received=received, sent=sent)
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown()
        if profiles:
            os.unlink(profiles)


if __name__ == "__main__":
    main()
