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
  flood           --writers ControlCommand writers, ids from --id upward, all streaming
  listen          not an attack: a foreign *vehicle* built on the seed IDL alone. Reads
                  ControlCommand (reliable, exclusive) in --partition (absent: none, the
                  default partition) and, with --vehicle-info, publishes DeviceInfo for --id as
                  a vehicle. Prints how many samples it got for --id and for other vehicles.

Every command the rogue streams carries throttle --throttle (default 31111), so a test can tell
from the vehicle's record whether any rogue sample was applied. Runs for --seconds, then prints
one JSON line {"attack": ..., "samples": N, "matched": bool} and exits 0.
"""

import argparse
import json
import os
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
        matched = wait_matched(ws[-1])
        ids = [a.id + i for i in range(a.writers)]
        samples = stream(ws, ids, a.dest, a.throttle, a.seconds, hz=20)
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
    else:
        p.error(f"unknown attack {a.attack!r}")
    print(json.dumps({"attack": a.attack, "samples": samples, "matched": matched}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
