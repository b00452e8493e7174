#!/usr/bin/env python3
"""Turns a fleet capture (testkit/rtps_spray.py's format) into seeds of the `rtps` fuzz target.

    fuzz/seed-capture/seeds.py CAPTURE OUT_DIR

Keeps what the vehicle (participant 0: ports 7400, 7401 multicast and 7410, 7411 unicast)
received, finds the vehicle's GUID prefix (the commonest INFO_DESTINATION of its unicast
datagrams) and replaces it everywhere with the fuzz target's participant's (rtps.rs,
VEHICLE_PREFIX). Each seed is one window of the capture preceded by the last DISCOVERY
datagrams before it that carry the remotes' SPDP and SEDP samples (who is there, which writers
and readers), framed as the target reads its input (u16 little-endian length, then the
datagram), at most 64 in all.
"""
import collections
import struct
import sys
from pathlib import Path

VEHICLE_PREFIX = bytes([0x01, 0x0F, 0x52, 0x4F, 0x56, 0x45, 0, 0, 0, 0, 0, 0x64])
VEHICLE_PORTS = {7400, 7401, 7410, 7411}
DISCOVERY = 24
WINDOW = 36
MAX_SEEDS = 24


def records(data):
    at = 0
    while at + 8 <= len(data):
        port, length = struct.unpack_from("<HH", data, at + 4)
        yield port, data[at + 8 : at + 8 + length]
        at += 8 + length


def submessages(datagram):
    """The submessages of an RTPS datagram (after its 20-byte header): (kind, its bytes with
    its 4-byte header), in order; a zero length ends the walk."""
    at = 20
    while at + 4 <= len(datagram):
        kind, flags = datagram[at], datagram[at + 1]
        (length,) = struct.unpack_from("<H" if flags & 1 else ">H", datagram, at + 2)
        yield kind, datagram[at : at + 4 + length]
        if length == 0:
            break
        at += 4 + length


def info_destinations(datagram):
    for kind, sub in submessages(datagram):
        if kind == 0x0E and len(sub) >= 16:
            yield bytes(sub[4:16])


# SPDP and SEDP writers' entity ids (RTPS 2.5 9.3.1.3): participant, publications, subscriptions.
DISCOVERY_WRITERS = {bytes.fromhex("000100c2"), bytes.fromhex("000003c2"), bytes.fromhex("000004c2")}


def discovery(datagram):
    """Whether the datagram carries an SPDP or SEDP DATA."""
    return any(kind == 0x15 and sub[12:16] in DISCOVERY_WRITERS for kind, sub in submessages(datagram))


def main():
    capture, out = Path(sys.argv[1]), Path(sys.argv[2])
    received = [d for port, d in records(capture.read_bytes()) if port in VEHICLE_PORTS]
    dests = collections.Counter(
        p for port, d in records(capture.read_bytes()) if port in (7410, 7411) for p in info_destinations(d)
    )
    vehicle, _ = dests.most_common(1)[0]
    fixed = [d.replace(vehicle, VEHICLE_PREFIX) for d in received]
    out.mkdir(parents=True, exist_ok=True)
    step = max(WINDOW // 2, len(fixed) // MAX_SEEDS)
    for n, start in enumerate(range(0, len(fixed), step)):
        # Discovery so far (every SPDP and SEDP sample before the window, remotes' first),
        # then the window: the window's writers are known when its traffic arrives.
        before = [d for d in fixed[:start] if discovery(d) and d[8:20] != VEHICLE_PREFIX]
        head = before[-DISCOVERY:]
        seed = b"".join(struct.pack("<H", len(d)) + d for d in head + fixed[start : start + WINDOW])
        (out / f"fleet-{n:02}").write_bytes(seed)
    print(f"vehicle prefix {vehicle.hex()}; {len(received)} datagrams to it; seeds in {out}")


if __name__ == "__main__":
    main()
