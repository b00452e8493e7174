#!/usr/bin/env python3
"""Seeds of the `rtps` fuzz target with the submessages a short capture lacks: each is a
captured seed (discovery and traffic) followed by GAP, HEARTBEAT_FRAG, NACK_FRAG and ACKNACK
submessages with ordinary values, addressed as the captured HEARTBEATs and ACKNACKs are. The
fuzzer mutates the values from there.

    fuzz/seed-capture/crafted.py CORPUS_DIR     (reads CORPUS_DIR/fleet-*, writes crafted-*)
"""
import struct
import sys
from pathlib import Path


# The fuzz target's participant (fuzz/src/rtps.rs VEHICLE_PREFIX), not a remote, and the walk
# over a datagram's submessages: seeds.py's, beside this script.
from seeds import VEHICLE_PREFIX as VEHICLE, submessages


def frames(seed):
    at = 0
    while at + 2 <= len(seed):
        (n,) = struct.unpack_from("<H", seed, at)
        yield seed[at + 2 : at + 2 + n]
        at += 2 + n


def sn(v):
    return struct.pack("<iI", v >> 32, v & 0xFFFFFFFF)


def sub(kind, flags, body):
    return struct.pack("<BBH", kind, flags | 1, len(body)) + body


def main():
    corpus = Path(sys.argv[1])
    # The first captured seed with a remote writer's HEARTBEAT, and the first with an ACKNACK
    # from a remote reader to one of our writers.
    def first(wanted):
        for path in sorted(corpus.glob("fleet-*")):
            seed = path.read_bytes()
            for d in frames(seed):
                for k, s in submessages(d):
                    if d[8:20] != VEHICLE and wanted(k, s):
                        return seed, d, s
        raise SystemExit("no seed has what is needed")

    seed, hb_dgram, hb_sub = first(lambda k, s: k == 0x07 and s[11] in (0x02, 0x03))
    ack_seed, ack_dgram, ack_sub = first(lambda k, s: k == 0x06 and s[11] == 0x02)
    reader, writer = hb_sub[4:8], hb_sub[8:12]
    head = hb_dgram[:20]
    info = b"".join(s for k, s in submessages(hb_dgram) if k in (0x0E, 0x09))
    bitmap = lambda base, bits, words: sn(base) + struct.pack("<I", bits) + b"".join(struct.pack("<I", w) for w in words)
    to_reader = {
        "gap": sub(0x08, 0, reader + writer + sn(3) + bitmap(6, 32, [0x5])),
        "heartbeat-frag": sub(0x13, 0, reader + writer + sn(4) + struct.pack("<I", 3) + struct.pack("<i", 7)),
        "heartbeat": sub(0x07, 0, reader + writer + sn(1) + sn(40) + struct.pack("<i", 90)),
    }
    a_reader, a_writer = ack_sub[4:8], ack_sub[8:12]
    ack_info = b"".join(s for k, s in submessages(ack_dgram) if k in (0x0E, 0x09))
    to_writer = {
        "acknack": sub(0x06, 2, a_reader + a_writer + bitmap(1, 64, [0xFFFF0000, 0x0F]) + struct.pack("<i", 77)),
        "nack-frag": sub(0x12, 0, a_reader + a_writer + sn(1) + struct.pack("<I", 1) + struct.pack("<I", 32) + struct.pack("<I", 0xF0000000) + struct.pack("<i", 78)),
    }
    for name, s in to_reader.items():
        extra = head + info + s
        (corpus / f"crafted-{name}").write_bytes(seed + struct.pack("<H", len(extra)) + extra)
    for name, s in to_writer.items():
        extra = ack_dgram[:20] + ack_info + s
        (corpus / f"crafted-{name}").write_bytes(ack_seed + struct.pack("<H", len(extra)) + extra)
    print("reader", reader.hex(), "writer", writer.hex(), "ack to", a_writer.hex())


if __name__ == "__main__":
    main()
