#!/usr/bin/env python3
"""A pymavlink ground station for rove's routing tests: talks to the autopilot through rove as
QGroundControl does.

- It listens on UDP (--connection udpin:127.0.0.1:0, as QGroundControl listens on 14550) and
  answers whoever sent last; or connects (udpout:, tcp:).
- HEARTBEAT once a second as a GCS (MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID), from --sysid (not
  255: rove is the autopilot's GCS id) and --compid.
- --params: once the autopilot (--target) is heard, PARAM_REQUEST_LIST to it.
- --sticks-hz N: MANUAL_CONTROL to the autopilot at N Hz, as QGC's joystick does.
- --ping-hz N: COMMAND_LONG (MAV_CMD_REQUEST_MESSAGE of AUTOPILOT_VERSION, confirmation 0..255)
  at N Hz; the record's `sent` lines carry the wall time, for latency through rove.

The GCS operator-control protocol, as QGroundControl PR #14560 speaks it (--operator-control):
it reads CONTROL_STATUS (id 512; pymavlink 2.4.50 predates it: read from the raw frame), sends
MANUAL_CONTROL only while the system manager names it `gcs_main`, and asks for control or gives
it back with MAV_CMD_REQUEST_OPERATOR_CONTROL (32100) to the manager's component when told to:
--commands FILE is read for new lines, each one of `request`, `release`, `rogue` (send
MANUAL_CONTROL from now on whatever CONTROL_STATUS says, as a station without the protocol).
It records `control_status` (flags, gcs_main, src, comp), `control_ack` (result) and `sent` lines.

Everything it sends and receives is written to --record as JSON lines with a monotonic `t` and
a wall-clock `wall_us`: `{"event": "rx", "type", "src", "comp", "seq"}` per frame received,
`{"event": "sent", "type", ...}` per message sent. The first line is {"event": "ready", "port":
P} with the UDP port it listens on.
"""

import argparse
import json
import os
import time

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--connection", required=True)
    p.add_argument("--record", required=True)
    p.add_argument("--sysid", type=int, default=250)
    p.add_argument("--compid", type=int, default=190)
    p.add_argument("--target", type=int, default=1, help="the autopilot's system id")
    p.add_argument("--params", action="store_true")
    p.add_argument("--sticks-hz", type=float, default=0.0)
    p.add_argument("--ping-hz", type=float, default=0.0)
    p.add_argument("--operator-control", action="store_true")
    p.add_argument("--commands", default=None)
    p.add_argument("--duration", type=float, default=120.0, help="exit after this long (bounded)")
    a = p.parse_args()

    out = open(a.record, "a", buffering=1)

    def record(event, **fields):
        fields.update(event=event, t=time.monotonic(), wall_us=int(time.time() * 1e6))
        out.write(json.dumps(fields) + "\n")

    m = mavutil.mavlink_connection(a.connection, source_system=a.sysid, source_component=a.compid,
                                   autoreconnect=True)
    port = m.port.getsockname()[1] if a.connection.startswith("udpin:") else None
    record("ready", pid=os.getpid(), port=port)

    def send(what, **fields):
        try:
            what()
            record("sent", **fields)
        except OSError:
            pass  # udpin before rove spoke

    start = time.monotonic()
    next_hb = start
    next_stick = start
    next_ping = start
    ping = 0
    heard = False
    asked = False
    gcs_main = None
    manager = (a.target, 191)
    rogue = False
    read_commands = 0
    while time.monotonic() - start < a.duration:
        now = time.monotonic()
        if now >= next_hb:
            next_hb += 1.0
            send(lambda: m.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS,
                                              mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                                              mavutil.mavlink.MAV_STATE_ACTIVE),
                 type="HEARTBEAT")
        if a.params and heard and not asked:
            asked = True
            send(lambda: m.mav.param_request_list_send(a.target, 1), type="PARAM_REQUEST_LIST")
        if a.commands and os.path.exists(a.commands):
            lines = open(a.commands).read().splitlines()
            for line in lines[read_commands:]:
                if line in ("request", "release"):
                    p1 = 1 if line == "request" else 0
                    send(lambda: m.mav.command_long_send(manager[0], manager[1], 32100, 0, p1, 0,
                                                         10, a.sysid, 0, 0, 0),
                         type="REQUEST_OPERATOR_CONTROL", request=p1)
                elif line == "rogue":
                    rogue = True
                    record("rogue")
            read_commands = len(lines)
        in_control = not a.operator_control or rogue or gcs_main == a.sysid
        if a.sticks_hz > 0 and heard and in_control and now >= next_stick:
            next_stick = max(next_stick + 1.0 / a.sticks_hz, now)
            send(lambda: m.mav.manual_control_send(a.target, 300, 0, 700, 0, 0),
                 type="MANUAL_CONTROL")
        if a.ping_hz > 0 and heard and now >= next_ping:
            next_ping = max(next_ping + 1.0 / a.ping_hz, now)
            n = ping % 256
            ping += 1
            send(lambda: m.mav.command_long_send(
                a.target, 1, mavutil.mavlink.MAV_CMD_REQUEST_MESSAGE, n,
                mavutil.mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0),
                type="COMMAND_LONG", confirmation=n)
        msg = m.recv_match(blocking=True, timeout=0.005)
        if msg is None or msg.get_type() == "BAD_DATA":
            continue
        src = msg.get_srcSystem()
        if src == a.target and msg.get_type() == "HEARTBEAT":
            heard = True
        if msg.get_type() == "UNKNOWN_512":
            # pymavlink leaves an unknown message's header unread: the frame has it.
            buf = bytes(msg.get_msgbuf())
            payload = buf[10:10 + buf[1]] + bytes(12)
            gcs_main = payload[1]
            manager = (buf[5], buf[6])
            record("control_status", flags=payload[0], gcs_main=gcs_main, src=buf[5], comp=buf[6])
            continue
        if msg.get_type() == "COMMAND_ACK" and msg.command == 32100:
            record("control_ack", result=msg.result, src=src, comp=msg.get_srcComponent())
            continue
        record("rx", type=msg.get_type(), src=src, comp=msg.get_srcComponent(), seq=msg.get_seq())
    record("exit")


if __name__ == "__main__":
    main()
