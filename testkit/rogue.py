#!/usr/bin/env python3
"""A foreign DDS peer for rove's tests, mostly a rogue one for the trust tests: a foreign
participant (Cyclone DDS) on the same domain that speaks rove's wire model (the three topics,
their type names, XCDR1) and tries to
take or disturb a vehicle.

    rogue.py ATTACK [--options]   (run inside the test's network namespace)

Attacks:
  inflate         stream ControlCommand as --id at --strength (e.g. 65534) to --dest
  forge-accept    publish an ACCEPT naming --owner as consenting, then stream as --id at 65535
  spoof-src       stream ControlCommand as --id (an honest operator's id) from this participant
  forge-finish    publish a FINISH in --id's name (a grant holder's) for --dest
  request-finish  REQUEST --dest from --owner claiming --priority, then FINISH it
  device-info     publish DeviceInfo for --id (a vehicle's) naming --controller as its owner
  flood           --writers ControlCommand writers, ids from --id upward, all streaming at
                  --hz each (default 20); with --requests N, also N RequestControl writers,
                  ids from --id + 10000 upward, each sending a REQUEST for --dest at
                  --request-hz that names --nobody as the owner (so no honest peer answers it:
                  it only fills histories). Says "flooding" on stderr once matched; its
                  summary adds "requests" (sent) and "seconds" (how long it sent).
                  With --batch N, each writer's commands leave as one RTPS datagram of N DATA
                  submessages per period (as a DDS that batches writes sends them; Cyclone's
                  Python binding cannot batch, so these datagrams are built here, in the
                  writers' names, with their own sequence numbers, to the domain's user
                  multicast group).
  listen          not an attack: a foreign *vehicle* built on the seed IDL alone. Reads
                  ControlCommand (reliable, exclusive) in --partition (absent: none, the
                  default partition) and, with --vehicle-info, publishes DeviceInfo for --id as
                  a vehicle. Prints how many samples it got for --id and for other vehicles.
  observe         not an attack: a foreign observer that joins late, with the seed's DeviceInfo
                  reader QoS (reliable, transient local, liveliness lease 3 s). For --seconds
                  it takes every DeviceInfo sample and prints the devices it lists (type and
                  controller_id, by id), when each was first heard (ms after its reader was
                  made), how many instance changes it saw (disposals, writers gone), and how
                  many times a writer's liveliness was lost.

Every command the rogue streams carries throttle --throttle (default 31111), so a test can tell
from the vehicle's record whether any rogue sample was applied. Runs for --seconds, then prints
one JSON line {"attack": ..., "samples": N, "matched": bool} and exits 0.
"""

import argparse
import json
import os
import socket
import struct
import sys
import time
from dataclasses import dataclass

os.environ.setdefault(
    "CYCLONEDDS_URI",
    "<CycloneDDS><Domain><General><Interfaces>"
    '<NetworkInterface name="lo" multicast="true"/>'
    "</Interfaces><AllowMulticast>true</AllowMulticast></General></Domain></CycloneDDS>",
)

from cyclonedds.core import Policy, Qos  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.idl import IdlStruct  # noqa: E402
from cyclonedds.idl.annotations import key  # noqa: E402
from cyclonedds.idl.types import int16, int32, int64, uint64  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.sub import DataReader, Subscriber  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402
from cyclonedds.util import duration  # noqa: E402

# IDL enums are 4-byte values on the wire: plain int32 fields carry them exactly.
VEHICLE, CONTROLLER = 0, 1
PROBE, MOVEMENT, MODE = 0, 1, 2
MANUAL = 0
REQUEST, ACCEPT, REFUSE, FINISH = 0, 1, 2, 3
UNIX_EPOCH_100NS = 122_192_928_000_000_000


@dataclass
class MovementCommand(IdlStruct, typename="RoVe::MovementCommand"):
    throttle: int16
    roll: int16
    pitch: int16
    yaw: int16


@dataclass
class ControlCommand(IdlStruct, typename="RoVe::ControlCommand"):
    src_id: int64
    dest_id: int64
    key("dest_id")
    command_type: int32
    movement_command: MovementCommand
    mode: int32
    timestamp: uint64


@dataclass
class DeviceInfo(IdlStruct, typename="RoVe::DeviceInfo"):
    device_id: int64
    key("device_id")
    name: str
    device_type: int32
    controller_id: int64


@dataclass
class RequestControl(IdlStruct, typename="RoVe::RequestControl"):
    src_id: int64
    dest_id: int64
    current_controller_id: int64
    src_priority: int32
    ack: int32
    timestamp: uint64


def stamp():
    return UNIX_EPOCH_100NS + time.time_ns() // 100


def reliable():
    return [Policy.Reliability.Reliable(max_blocking_time=duration(milliseconds=5))]


def command_writer(dp, topic, strength):
    qos = Qos(
        *reliable(),
        Policy.History.KeepLast(1),
        Policy.Ownership.Exclusive,
        Policy.OwnershipStrength(strength),
    )
    return DataWriter(dp, topic, qos=qos)


def wait_matched(writer, seconds=5.0):
    """Until a reader matched (a rove process discovered us), bounded."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if writer.get_matched_subscriptions():
            return True
        time.sleep(0.02)
    return False


def command(src, dest, throttle):
    return ControlCommand(
        src_id=src,
        dest_id=dest,
        command_type=MOVEMENT,
        movement_command=MovementCommand(throttle=throttle, roll=0, pitch=0, yaw=0),
        mode=MANUAL,
        timestamp=stamp(),
    )


def request(src, dest, owner, priority, ack, at):
    return RequestControl(
        src_id=src,
        dest_id=dest,
        current_controller_id=owner,
        src_priority=priority,
        ack=ack,
        timestamp=at,
    )


def stream(writers, ids, dest, throttle, seconds, hz=100):
    """Every writer sends one command per period for `seconds`; returns the count."""
    sent = 0
    end = time.monotonic() + seconds
    period = 1.0 / hz
    while time.monotonic() < end:
        for writer, src in zip(writers, ids):
            writer.write(command(src, dest, throttle))
            sent += 1
        time.sleep(period)
    return sent


USER_MULTICAST = "239.255.0.1"
CYCLONE_VENDOR = bytes([0x01, 0x10])


class Batches:
    """A writer's commands as RTPS datagrams of `count` DATA submessages each: an INFO_TS (the
    send time, so that the samples are fresh) and the DATA, little endian, CDR, to the user
    multicast port of `domain` (7400 + 250 * domain + 1). The writer itself never writes, so
    these are its samples from sequence number 1 on."""

    def __init__(self, writer, src, a):
        guid = writer.guid.bytes
        self.prefix, self.entity = guid[:12], guid[12:]
        self.src, self.a = src, a
        self.sn = 1
        self.port = 7400 + 250 * a.domain + 1

    def datagram(self, count):
        now_ns = time.time_ns()
        seconds, frac = now_ns // 10**9, ((now_ns % 10**9) << 32) // 10**9
        out = [b"RTPS", bytes([2, 1]), CYCLONE_VENDOR, self.prefix,
               struct.pack("<BBHII", 0x09, 0x01, 8, seconds, frac)]  # INFO_TS
        for _ in range(count):
            payload = struct.pack(
                "<qqIhhhhiQ", self.src, self.a.dest, MOVEMENT, self.a.throttle, 0, 0, 0,
                MANUAL, stamp())
            body = struct.pack("<HH4s4siI", 0, 16, bytes(4), self.entity, self.sn >> 32,
                               self.sn & 0xFFFFFFFF) + bytes([0, 1, 0, 0]) + payload
            out.append(struct.pack("<BBH", 0x15, 0x05, len(body)) + body)  # DATA, E|D
            self.sn += 1
        return b"".join(out)


def flood(commands, requests, ids, rids, a):
    """Paced to an absolute schedule, so that the rates hold whatever a write costs: every
    period each command writer sends one command and, every `a.hz / a.request_hz` periods,
    each request writer one REQUEST. Bounded by `a.seconds`; returns the counts and the time
    it sent for."""
    sent, asked = 0, 0
    batches = [Batches(w, src, a) for w, src in zip(commands, ids)] if a.batch else []
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
    period = 1.0 / a.hz
    request_every = max(1, round(a.hz / a.request_hz)) if a.request_hz > 0 else 0
    start = time.monotonic()
    end, due, tick = start + a.seconds, start, 0
    while time.monotonic() < end:
        for b in batches:
            sock.sendto(b.datagram(a.batch), (USER_MULTICAST, b.port))
            sent += a.batch
        for writer, src in zip(commands if not a.batch else [], ids):
            writer.write(command(src, a.dest, a.throttle))
            sent += 1
        if request_every and tick % request_every == 0:
            for writer, src in zip(requests, rids):
                writer.write(request(src, a.dest, a.nobody, 1, REQUEST, stamp()))
                asked += 1
        tick += 1
        due += period
        time.sleep(max(0.0, due - time.monotonic()))
    return sent, asked, time.monotonic() - start


def observe(dp, infos, seconds):
    """A late-joining foreign observer of DeviceInfo (the seed's reader QoS); see the docs."""
    qos = Qos(
        *reliable(),
        Policy.Durability.TransientLocal,
        Policy.History.KeepLast(1),
        Policy.Liveliness.Automatic(lease_duration=duration(seconds=3)),
    )
    reader = DataReader(dp, infos, qos=qos)
    start = time.monotonic()
    devices, first_ms, changes, lost = {}, {}, 0, 0
    while time.monotonic() < start + seconds:
        for s in reader.take(N=256):
            if isinstance(s, DeviceInfo):
                key = str(s.device_id)
                first_ms.setdefault(key, round((time.monotonic() - start) * 1000))
                devices[key] = {"type": s.device_type, "controller_id": s.controller_id}
            else:
                changes += 1  # an invalid sample: an instance disposed or without writers
        lost += reader.get_liveliness_changed_status().not_alive_count_change
        time.sleep(0.01)
    print(json.dumps({"attack": "observe", "devices": devices, "first_ms": first_ms,
                      "instance_changes": changes, "liveliness_lost": lost,
                      "matched": bool(reader.get_matched_publications())}), flush=True)
    return 0


def main():
    p = argparse.ArgumentParser()
    p.add_argument("attack")
    p.add_argument("--domain", type=int, default=0)
    p.add_argument("--id", type=int, default=13)
    p.add_argument("--dest", type=int, default=100)
    p.add_argument("--owner", type=int, default=11)
    p.add_argument("--controller", type=int, default=13)
    p.add_argument("--strength", type=int, default=65534)
    p.add_argument("--priority", type=int, default=400)
    p.add_argument("--throttle", type=int, default=31111)
    p.add_argument("--writers", type=int, default=300)
    p.add_argument("--seconds", type=float, default=2.0)
    p.add_argument("--partition", default=None)
    p.add_argument("--vehicle-info", action="store_true")
    p.add_argument("--hz", type=float, default=20.0)
    p.add_argument("--requests", type=int, default=0)
    p.add_argument("--request-hz", type=float, default=10.0)
    p.add_argument("--nobody", type=int, default=999)
    p.add_argument("--batch", type=int, default=0)
    a = p.parse_args()

    dp = DomainParticipant(a.domain)
    commands = Topic(dp, "ControlCommand", ControlCommand)
    requests = Topic(dp, "RequestControl", RequestControl)
    infos = Topic(dp, "DeviceInfo", DeviceInfo)
    req_qos = Qos(*reliable(), Policy.History.KeepLast(16))
    samples, matched = 0, False

    if a.attack in ("inflate", "spoof-src"):
        w = command_writer(dp, commands, a.strength)
        matched = wait_matched(w)
        samples = stream([w], [a.id], a.dest, a.throttle, a.seconds)
    elif a.attack == "forge-accept":
        rw = DataWriter(dp, requests, qos=req_qos)
        w = command_writer(dp, commands, 65535)
        matched = wait_matched(rw) and wait_matched(w)
        rw.write(request(a.id, a.dest, a.owner, a.priority, ACCEPT, stamp()))
        samples = 1 + stream([w], [a.id], a.dest, a.throttle, a.seconds)
    elif a.attack == "forge-finish":
        rw = DataWriter(dp, requests, qos=req_qos)
        matched = wait_matched(rw)
        end = time.monotonic() + a.seconds
        while time.monotonic() < end:
            # Stamped "now", and at the far end of time: neither may end the grant.
            for at in (stamp(), 2**64 - 1):
                rw.write(request(a.id, a.dest, a.owner, a.priority, FINISH, at))
                samples += 1
            time.sleep(0.05)
    elif a.attack == "request-finish":
        rw = DataWriter(dp, requests, qos=req_qos)
        matched = wait_matched(rw)
        at = stamp()
        end = time.monotonic() + a.seconds / 2
        while time.monotonic() < end:
            rw.write(request(a.id, a.dest, a.owner, a.priority, REQUEST, at))
            samples += 1
            time.sleep(0.1)
        end = time.monotonic() + a.seconds / 2
        while time.monotonic() < end:
            rw.write(request(a.id, a.dest, a.owner, a.priority, FINISH, at))
            samples += 1
            time.sleep(0.1)
    elif a.attack == "device-info":
        qos = Qos(
            *reliable(),
            Policy.Durability.TransientLocal,
            Policy.History.KeepLast(1),
            Policy.Liveliness.Automatic(lease_duration=duration(seconds=1)),
        )
        w = DataWriter(dp, infos, qos=qos)
        matched = wait_matched(w)
        end = time.monotonic() + a.seconds
        while time.monotonic() < end:
            w.write(DeviceInfo(device_id=a.id, name="rogue", device_type=VEHICLE,
                               controller_id=a.controller))
            samples += 1
            time.sleep(0.05)
    elif a.attack == "flood":
        ws = [command_writer(dp, commands, a.strength) for _ in range(a.writers)]
        rws = [DataWriter(dp, requests, qos=req_qos) for _ in range(a.requests)]
        matched = wait_matched(ws[-1]) and all(wait_matched(w) for w in rws[-1:])
        ids = [a.id + i for i in range(a.writers)]
        rids = [a.id + 10000 + i for i in range(a.requests)]
        print("flooding", file=sys.stderr, flush=True)
        samples, asked, seconds = flood(ws, rws, ids, rids, a)
        print(json.dumps({"attack": a.attack, "samples": samples, "requests": asked,
                          "seconds": round(seconds, 3), "matched": matched}), flush=True)
        return 0
    elif a.attack == "listen":
        sub_qos = Qos(Policy.Partition([a.partition])) if a.partition is not None else None
        sub = Subscriber(dp, qos=sub_qos)
        reader = DataReader(sub, commands, qos=Qos(
            *reliable(), Policy.History.KeepLast(1), Policy.Ownership.Exclusive))
        info_qos = Qos(
            *reliable(),
            Policy.Durability.TransientLocal,
            Policy.History.KeepLast(1),
            Policy.Liveliness.Automatic(lease_duration=duration(seconds=1)),
        )
        info = DataWriter(dp, infos, qos=info_qos) if a.vehicle_info else None
        others, next_info = 0, 0.0
        end = time.monotonic() + a.seconds
        while time.monotonic() < end:
            if info is not None and time.monotonic() >= next_info:
                info.write(DeviceInfo(device_id=a.id, name="seed", device_type=VEHICLE,
                                      controller_id=a.id))
                next_info = time.monotonic() + 0.5
            for s in reader.take(N=64):
                if not isinstance(s, ControlCommand):
                    continue  # an invalid sample (dispose)
                if s.dest_id == a.id:
                    samples += 1
                else:
                    others += 1
            matched = matched or bool(reader.get_matched_publications())
            time.sleep(0.01)
        print(json.dumps({"attack": a.attack, "samples": samples, "others": others,
                          "matched": matched}), flush=True)
        return 0
    elif a.attack == "observe":
        return observe(dp, infos, a.seconds)
    else:
        p.error(f"unknown attack {a.attack!r}")
    print(json.dumps({"attack": a.attack, "samples": samples, "matched": matched}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
