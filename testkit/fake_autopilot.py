#!/usr/bin/env python3
"""A pymavlink autopilot for rove's MAVLink tests: behaves like ArduPilot as a GCS sees it.

What it copies from a real ArduPilot (docs/mavlink.md, "ArduPilot as a GCS sees it"):
- RC_CHANNELS_OVERRIDE is taken only from the GCS system id (--gcs-sysid, ArduPilot's
  MAV_GCS_SYSID, default 255) and only when target_system is ours; others are recorded as ignored.
- ch1-8: 0 releases the channel, 65535 ignores it; ch9-18: 0 and 65535 ignore, 65534 releases.
- An override expires --override-timeout seconds after the last one for that channel
  (RC_OVERRIDE_TIME, 3 s by default).
- MANUAL_CONTROL is taken when its target is ours; it expires like an override.
- MAV_CMD_DO_SET_MODE (param1 = custom mode flag, param2 = custom_mode; PX4: param2 main mode,
  param3 sub mode) switches the mode and is answered with COMMAND_ACK; the HEARTBEAT reports it.
- HEARTBEAT at --heartbeat-hz (1 Hz like the real one); with --mode-heartbeat also at once on
  every mode change, before the COMMAND_ACK, as a real ArduRover does (without it, a new mode
  shows only at the next regular beat: the slower model, which tests the COMMAND_ACK path).
- udpout:HOST:PORT is ArduPilot's UDP client (`--serialN udpclient:...`): a connected socket on
  a port of its own, speaking first. A ground station on udpin learns its address only from its
  first datagram, and only datagrams from HOST:PORT reach it.
- tcpin:HOST:PORT is ArduPilot's TCP server: it reads a client's bytes at its own tick
  (--tcp-tick, 10 ms) and a client that has closed loses what it wrote but was not read yet
  (recorded as tcp_client_closed with the unread byte count): a GCS that writes its last
  command and closes at once is not obeyed. One client at a time; the next is accepted after.
- Optional GCS failsafe (--gcs-failsafe S): no GCS traffic for S seconds -> the safe mode.
- Default telemetry like ArduPilot's first serial port (--telemetry ardupilot, the default):
  once a second a burst of ardupilotmega messages outside `common` (AHRS, AHRS2, MEMINFO,
  SIMSTATE, EKF_STATUS_REPORT), half a second out of phase with the HEARTBEAT. SIMSTATE's roll
  carries the bytes FE F0 (a MAVLink 1 start claiming 240 bytes) and the burst ends with a
  well-formed frame of an id no dialect knows, whose payload also holds FE F0: a reader that
  trusts a stray start byte's length waits for the next burst.
- A mode in --fail-modes (e.g. 10, Rover AUTO without a mission) is answered MAV_RESULT_FAILED
  with a STATUSTEXT, and the mode stays as it was.
- SYS_STATUS with each HEARTBEAT: a 3S battery at --battery-pct (default 100) that drains by
  --battery-drain percent a second (default 0), 12.6 V full to 10.5 V empty; --battery-pct -1
  sends the autopilot's "unknown" values (UINT16_MAX mV, -1 %).

The GCS operator-control protocol (MAVLink development.xml), as ArduPilot PRs #29252/#33332
implement it, with --system-manager: the autopilot streams CONTROL_STATUS (SYSTEM_MANAGER,
TAKEOVER_ALLOWED with --takeover-allowed, gcs_main) with each HEARTBEAT and on every change, and
takes RC_CHANNELS_OVERRIDE and MANUAL_CONTROL only from gcs_main. MAV_CMD_REQUEST_OPERATOR_CONTROL
(32100): a request is granted (ACCEPTED) when nobody is in control, the requester already is, or
takeover is allowed; otherwise it is answered FAILED and forwarded to the station in control. A
release by the station in control frees the role. --gcs-main N: station N is in control at start;
--release-after S: it lets go S seconds after start; --forward-request-at S1,S2,...: at each, a
request of station --other-gcs (250) is forwarded to whoever is in control (recorded, with the
ACK it gets). pymavlink 2.4.50 predates these
messages: CONTROL_STATUS is packed by hand (CRC_EXTRA 21).

Test knobs: --ignore-mode-commands N (drop the first N mode commands: no ACK), --deny-modes,
--garbage (random bytes between messages), --foreign-sysid N (a second system that also sends
HEARTBEATs and COMMAND_ACKs), --stop-reading-after S (stop reading, as a wedged autopilot whose
receive buffer fills).

Everything it receives and does is written to --record as JSON lines with a monotonic time `t`.
The first line is {"event": "ready", "port": P} once the link is open; P is the UDP or TCP port
it listens on, so a test can pass port 0 and read the real one.
"""

import argparse
import json
import os
import random
import select
import socket
import struct
import sys
import time

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil  # noqa: E402

ROVER_HOLD = 4
PX4_AUTO_LOITER = (4 << 16) | (3 << 24)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--connection", required=True,
                   help="pymavlink address: udpin:HOST:PORT, udpout:HOST:PORT, tcpin:HOST:PORT, or a serial device")
    p.add_argument("--baud", type=int, default=57600)
    p.add_argument("--record", required=True)
    p.add_argument("--sysid", type=int, default=1)
    p.add_argument("--compid", type=int, default=1)
    p.add_argument("--gcs-sysid", type=int, default=255)
    p.add_argument("--autopilot", choices=["ardupilot", "px4"], default="ardupilot")
    p.add_argument("--vehicle", choices=["rover", "copter"], default="rover")
    p.add_argument("--mode", type=int, default=None, help="initial custom_mode (default: the safe mode)")
    p.add_argument("--heartbeat-hz", type=float, default=1.0)
    p.add_argument("--mode-heartbeat", action="store_true",
                   help="a HEARTBEAT at once on every mode change (ArduPilot does)")
    p.add_argument("--override-timeout", type=float, default=3.0)
    p.add_argument("--gcs-failsafe", type=float, default=0.0)
    p.add_argument("--ignore-mode-commands", type=int, default=0)
    p.add_argument("--deny-modes", action="store_true")
    p.add_argument("--fail-modes", default="", help="comma-separated custom modes answered FAILED")
    p.add_argument("--telemetry", choices=["ardupilot", "none"], default="ardupilot")
    p.add_argument("--garbage", action="store_true")
    p.add_argument("--foreign-sysid", type=int, default=0)
    p.add_argument("--duration", type=float, default=120.0, help="exit after this long (bounded)")
    p.add_argument("--battery-pct", type=float, default=100.0,
                   help="battery remaining at start, percent (-1: unknown)")
    p.add_argument("--battery-drain", type=float, default=0.0, help="percent lost per second")
    p.add_argument("--tcp-tick", type=float, default=0.01,
                   help="tcpin: seconds between reads of the client's bytes")
    p.add_argument("--stop-reading-after", type=float, default=0.0,
                   help="stop reading S seconds after the GCS's first RC override (a wedged "
                        "autopilot whose receive buffer fills), still sending HEARTBEATs")
    p.add_argument("--system-manager", action="store_true")
    p.add_argument("--takeover-allowed", action="store_true")
    p.add_argument("--gcs-main", type=int, default=0)
    p.add_argument("--release-after", type=float, default=0.0)
    p.add_argument("--forward-request-at", default="", help="comma-separated seconds after start")
    p.add_argument("--other-gcs", type=int, default=250)
    a = p.parse_args()

    safe_mode = PX4_AUTO_LOITER if a.autopilot == "px4" else ROVER_HOLD
    mode = safe_mode if a.mode is None else a.mode
    out = open(a.record, "a", buffering=1)
    t0 = time.monotonic()

    def record(event, **fields):
        fields.update(event=event, t=time.monotonic(), wall_us=int(time.time() * 1e6))
        out.write(json.dumps(fields) + "\n")

    m = mavutil.mavlink_connection(a.connection, baud=a.baud, source_system=a.sysid,
                                   source_component=a.compid, autoreconnect=True)
    foreign = None
    if a.foreign_sysid:
        foreign = mavutil.mavlink.MAVLink(m, srcSystem=a.foreign_sysid, srcComponent=1)
    port = None
    tcp = a.connection.startswith("tcpin:")
    if a.connection.startswith("udpin:"):
        port = m.port.getsockname()[1]
    elif a.connection.startswith("udpout:"):
        # ArduPilot's udpclient: a connected socket, so only the GCS's address reaches it.
        m.port.connect((socket.gethostbyname(m.destination_addr[0]), m.destination_addr[1]))
        port = m.port.getsockname()[1]
    elif tcp:
        port = m.listen.getsockname()[1]
        if a.stop_reading_after:
            # A small receive buffer, inherited by the accepted connection (and no window
            # autotuning): once reading stops, the GCS's sends fill it within seconds.
            m.listen.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    fail_modes = {int(x) for x in a.fail_modes.split(",") if x}
    next_burst = time.monotonic() + 0.5
    burst_seq = 0
    record("ready", pid=os.getpid(), port=port)

    mav_type = (mavutil.mavlink.MAV_TYPE_GROUND_ROVER if a.vehicle == "rover"
                else mavutil.mavlink.MAV_TYPE_QUADROTOR)
    ap = (mavutil.mavlink.MAV_AUTOPILOT_PX4 if a.autopilot == "px4"
          else mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)
    overrides = {}  # channel -> (value, time)
    ignore_modes = a.ignore_mode_commands
    next_hb = time.monotonic()
    last_gcs = None
    first_override = None
    stopped_reading = False
    failsafe_fired = False
    gcs_main = a.gcs_main
    released = False
    forward_at = sorted(float(x) for x in a.forward_request_at.split(",") if x)

    def control_status():
        """CONTROL_STATUS (id 512), packed by hand: flags, gcs_main, gcs_secondary[10]."""
        flags = 1 | (2 if a.takeover_allowed else 0)
        payload = bytes([flags, gcs_main] + [0] * 10)
        seq = m.mav.seq
        m.mav.seq = (seq + 1) % 256
        head = bytes([len(payload), 0, 0, seq, a.sysid, a.compid, 0x00, 0x02, 0x00])
        crc = mavutil.mavlink.x25crc(head + payload)
        crc.accumulate(bytes([21]))
        send_raw(bytes([0xFD]) + head + payload + struct.pack("<H", crc.crc))

    def set_gcs_main(holder, why):
        nonlocal gcs_main
        if holder != gcs_main:
            gcs_main = holder
            record("gcs_main", gcs_main=holder, why=why)
            control_status()

    def send_raw(data):
        try:
            m.write(data)
        except OSError:
            pass  # udpin before the GCS spoke; a closed tcp peer

    def tcp_messages():
        """ArduPilot's TCP server: accept one client, read its bytes once per tick, and drop a
        client that has closed together with the bytes it wrote that were not read yet."""
        time.sleep(a.tcp_tick)
        if m.port is None:
            try:
                conn, addr = m.listen.accept()
            except (BlockingIOError, InterruptedError):
                return []
            conn.setsockopt(socket.SOL_TCP, socket.TCP_NODELAY, 1)
            conn.setblocking(False)
            m.port, m.fd = conn, conn.fileno()
            record("tcp_client", peer="%s:%d" % addr)
        poll = select.poll()
        poll.register(m.port, select.POLLIN | select.POLLRDHUP)
        closed = any(ev & (select.POLLRDHUP | select.POLLHUP | select.POLLERR)
                     for _, ev in poll.poll(0))
        if closed:
            unread = 0
            while True:
                try:
                    chunk = m.port.recv(65536)
                except OSError:
                    break
                if not chunk:
                    break
                unread += len(chunk)
            m.port.close()
            m.port, m.fd = None, m.listen.fileno()
            m.mav = mavutil.mavlink.MAVLink(m, srcSystem=a.sysid, srcComponent=a.compid)
            m.mav.robust_parsing = True
            record("tcp_client_closed", unread=unread)
            return []
        try:
            data = m.port.recv(65536)
        except OSError:  # nothing to read yet (BlockingIOError), or the socket failed
            return []
        try:
            return m.mav.parse_buffer(data) or []
        except Exception:  # a bad frame mid-buffer: what parsed before it is lost, as noise
            record("bad_data")
            return []

    while time.monotonic() - t0 < a.duration:
        now = time.monotonic()
        if now >= next_hb:
            next_hb = now + 1.0 / a.heartbeat_hz
            base = mavutil.mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            try:
                m.mav.heartbeat_send(mav_type, ap, base, mode, mavutil.mavlink.MAV_STATE_ACTIVE)
                if a.battery_pct < 0:
                    mv, pct = 65535, -1
                else:
                    pct = max(0.0, a.battery_pct - a.battery_drain * (now - t0))
                    mv = int(10500 + 2100 * pct / 100)
                m.mav.sys_status_send(0, 0, 0, 500, mv, -1, int(pct), 0, 0, 0, 0, 0, 0)
                if foreign is not None:
                    send_raw(foreign.heartbeat_encode(mav_type, ap, base, 99,
                                                      mavutil.mavlink.MAV_STATE_ACTIVE).pack(foreign))
                    send_raw(foreign.command_ack_encode(mavutil.mavlink.MAV_CMD_DO_SET_MODE,
                                                        mavutil.mavlink.MAV_RESULT_DENIED).pack(foreign))
                if a.garbage:
                    send_raw(bytes(random.getrandbits(8) for _ in range(40)) + b"\xfd\x09\x00")
                if a.system_manager:
                    control_status()
            except OSError:
                pass
        if a.system_manager and a.release_after and not released and now - t0 >= a.release_after:
            released = True
            set_gcs_main(0, "released")
        if a.system_manager and forward_at and now - t0 >= forward_at[0]:
            forward_at.pop(0)
            m.mav.command_long_send(gcs_main, 0, 32100, 0, 1, 0, 10, a.other_gcs, 0, 0, 0)
            record("control_forwarded", to=gcs_main, requester=a.other_gcs)
        if a.telemetry == "ardupilot" and now >= next_burst:
            next_burst = now + 1.0
            burst_seq = (burst_seq + 1) % 256
            stray = struct.unpack("<f", bytes([0x00, 0xFE, 0xF0, 0x3F]))[0]
            try:
                m.mav.ahrs_send(0.001, -0.002, 0.0, 0.9, 0.0, 0.01, 0.02)
                m.mav.ahrs2_send(0.01, -0.02, 1.5, 12.5, -353632640, 1491652352)
                m.mav.meminfo_send(0, 65535, 131072)
                m.mav.simstate_send(stray, 0.0, 1.5, 0.1, 0.0, -9.8, 0.0, 0.0, 0.0,
                                    -353632640, 1491652352)
                m.mav.ekf_status_report_send(0x1FF, 0.01, 0.02, 0.03, 0.04, 0.0, 0.0)
                # MAVLink 2, msgid 0x0FEEEE (unknown everywhere), payload with FE F0 inside.
                payload = bytes([0x11, 0xFE, 0xF0, 0x22, 0x33])
                head = bytes([len(payload), 0, 0, burst_seq, a.sysid, a.compid, 0xEE, 0xEE, 0x0F])
                crc = mavutil.mavlink.x25crc(head + payload)
                crc.accumulate(bytes([0]))  # CRC_EXTRA of an unknown message: anything
                send_raw(bytes([0xFD]) + head + payload + struct.pack("<H", crc.crc))
            except OSError:
                pass
        for ch in [c for c, (_, at) in overrides.items() if now - at > a.override_timeout]:
            del overrides[ch]
            record("override_expired", channel=ch)
        if a.gcs_failsafe and last_gcs is not None and not failsafe_fired and now - last_gcs > a.gcs_failsafe:
            failsafe_fired = True
            overrides.clear()
            mode = safe_mode
            record("gcs_failsafe", mode=mode)

        if (a.stop_reading_after and first_override is not None
                and now - first_override > a.stop_reading_after):
            if not stopped_reading:
                stopped_reading = True
                record("stopped_reading")
            time.sleep(0.02)
            continue
        if tcp:
            msgs = tcp_messages()
        else:
            msgs = [m.recv_match(blocking=True, timeout=0.02)]
        for msg in msgs:
            if msg is None:
                continue
            kind = msg.get_type()
            if kind == "BAD_DATA":
                record("bad_data")
                continue
            src, srccomp = msg.get_srcSystem(), msg.get_srcComponent()
            if src == a.gcs_sysid:
                last_gcs = time.monotonic()
                if failsafe_fired:
                    failsafe_fired = False
                    record("gcs_failsafe_cleared")
            if kind == "HEARTBEAT":
                record("heartbeat", src=src, comp=srccomp, type=msg.type, autopilot=msg.autopilot,
                       version=msg.get_msgbuf()[0] == 0xFD and 2 or 1)
            elif kind == "RC_CHANNELS_OVERRIDE":
                if first_override is None:
                    first_override = time.monotonic()
                raw = [getattr(msg, "chan%d_raw" % i, 0) for i in range(1, 19)]
                accepted = src == a.gcs_sysid and msg.target_system == a.sysid
                if a.system_manager and src != gcs_main:
                    accepted = False
                if accepted:
                    for i, v in enumerate(raw, start=1):
                        if i <= 8:
                            if v == 0:
                                overrides.pop(i, None)
                            elif v != 65535:
                                overrides[i] = (v, time.monotonic())
                        else:
                            if v == 65534:
                                overrides.pop(i, None)
                            elif v not in (0, 65535):
                                overrides[i] = (v, time.monotonic())
                record("rc_override", src=src, comp=srccomp, target=msg.target_system,
                       target_comp=msg.target_component, raw=raw, accepted=accepted,
                       active={str(c): v for c, (v, _) in sorted(overrides.items())})
            elif kind == "MANUAL_CONTROL":
                accepted = msg.target == a.sysid and src == a.gcs_sysid
                if a.system_manager and src != gcs_main:
                    accepted = False
                record("manual_control", src=src, target=msg.target, x=msg.x, y=msg.y, z=msg.z, r=msg.r,
                       accepted=accepted)
            elif kind == "COMMAND_LONG" and msg.command == 32100 and a.system_manager:
                asking = msg.param1 >= 0.5
                if not asking:
                    ok = src == gcs_main
                    if ok:
                        set_gcs_main(0, "released by %d" % src)
                elif gcs_main in (0, src) or a.takeover_allowed:
                    ok = True
                    set_gcs_main(src, "granted")
                else:
                    ok = False
                    m.mav.command_long_send(gcs_main, 0, 32100, 0, 1, 0, msg.param3, src, 0, 0, 0)
                    record("control_forwarded", to=gcs_main, requester=src)
                result = mavutil.mavlink.MAV_RESULT_ACCEPTED if ok else mavutil.mavlink.MAV_RESULT_FAILED
                record("control_request", src=src, request=asking, takeover=msg.param2 >= 0.5,
                       gcs=int(msg.param4), result=result)
                m.mav.command_ack_send(32100, result, 0, 0, src, srccomp)
            elif kind == "COMMAND_ACK" and msg.command == 32100:
                record("control_ack", src=src, result=msg.result)
            elif kind == "COMMAND_LONG":
                if msg.command != mavutil.mavlink.MAV_CMD_DO_SET_MODE or msg.target_system != a.sysid:
                    record("command", src=src, command=msg.command, target=msg.target_system,
                           confirmation=msg.confirmation)
                    continue
                if a.autopilot == "px4":
                    wanted = (int(msg.param2) << 16) | (int(msg.param3) << 24)
                else:
                    wanted = int(msg.param2)
                if ignore_modes > 0:
                    ignore_modes -= 1
                    record("set_mode", src=src, custom_mode=wanted, param1=msg.param1, answered=False)
                    continue
                if a.deny_modes:
                    result = mavutil.mavlink.MAV_RESULT_DENIED
                elif wanted in fail_modes:
                    result = mavutil.mavlink.MAV_RESULT_FAILED
                    m.mav.statustext_send(mavutil.mavlink.MAV_SEVERITY_WARNING,
                                          b"Flight mode change failed")
                else:
                    result = mavutil.mavlink.MAV_RESULT_ACCEPTED
                    mode = wanted
                record("set_mode", src=src, custom_mode=wanted, param1=msg.param1, answered=True,
                       result=result)
                if a.mode_heartbeat and result == mavutil.mavlink.MAV_RESULT_ACCEPTED:
                    # ArduPilot's GCS_MAVLINK::send_heartbeat on a mode change: at once.
                    m.mav.heartbeat_send(mav_type, ap, mavutil.mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                                         mode, mavutil.mavlink.MAV_STATE_ACTIVE)
                    record("mode_heartbeat", custom_mode=mode)
                m.mav.command_ack_send(mavutil.mavlink.MAV_CMD_DO_SET_MODE, result)
            else:
                record("other", type=kind, src=src)
    record("exit")


if __name__ == "__main__":
    try:
        main()
    except KeyboardInterrupt:
        sys.exit(0)
