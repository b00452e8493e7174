#!/usr/bin/env python3
"""A rove fleet's own RTPS datagrams, captured and sprayed back mutated: the live robustness
test of issue 29 (tests/spray.rs) and the seed capture for the RTPS fuzz target. Standard
library only. Run it inside the test's network namespace (`ip netns exec NS ...`): it captures
on and sends to that namespace's `lo`, and nothing leaves it.

    rtps_spray.py capture --seconds S --out FILE [--max-datagrams N] [--max-bytes B]
    rtps_spray.py spray --capture FILE --rate R --seconds S [--mode MODE] [--seed N]
                        [--max-datagrams N]
    rtps_spray.py forge --capture FILE --kind KIND --sn same|new [--count N] [--every S]
    rtps_spray.py census --capture FILE

`capture` reads every frame on `lo` through an AF_PACKET socket (needs root) and keeps the
UDP/IPv4 datagrams whose payload starts with b"RTPS". On `lo` each datagram passes twice, as
sent (PACKET_OUTGOING) and as received; only the received copy is kept. It prints
{"listening": true} once the socket is open (start the fleet after that line to capture its
discovery too), then, after S seconds or N datagrams or B payload bytes, whichever comes first,
one JSON line {"captured": N, "bytes": B, "seconds": S, "ports": {"PORT": COUNT, ...}}.

The capture file is a sequence of records, one per datagram, in capture order:

    offset 0  4 bytes  destination IPv4 address, network byte order (as in the IP header)
    offset 4  u16 LE   destination UDP port
    offset 6  u16 LE   payload length L
    offset 8  L bytes  the UDP payload (an RTPS message: b"RTPS", version, vendor, GUID prefix, ...)

`spray` sends mutated copies of the captured datagrams, each to the address and port its
original went to (multicast groups too: the socket sends multicast out of `lo`, TTL 0, looped
back), at R datagrams a second (R = 0: as fast as it can) for S seconds, and at most N
datagrams. Pacing is by the clock: datagram n is due at start + n / R, so a slow turn is made
up by the next ones rather than lost. Mutations, by --mode:

    flip      1 to 8 bytes after the 20-byte RTPS header XORed with random non-zero bytes
    splice    the head of one datagram (cut after its header) joined to the tail of another
    extreme   1 to 3 32-bit fields at 4-aligned offsets after the header set to 0xFFFFFFFF,
              0x80000000, 0 or 0x7FFFFFFF (little-endian, rove's and rustdds's wire order)
    truncate  a datagram cut short at a random length (sometimes inside the header)
    mixed     each datagram one of the four above, chosen at random (the default)

`forge` sends, for every participant whose SPDP announcement (DATA(p)) is in the capture, a
forged announcement to where the original went (`--count` times, `--every` seconds apart):

    --kind lease0   the participant's own announcement with its lease set to 0 s: "forget me
                    at once"
    --kind goodbye  its announcement turned into a goodbye (no payload; inline QoS KEY_HASH of
                    the participant, STATUS_INFO disposed and unregistered)
    --sn same       under the announcement's own sequence number: a repeat of one already seen
    --sn new        under a sequence number above it (1000 for lease0, 2000 for goodbye): as
                    a real one looks

It prints one JSON line {"forged": N, "participants": [PREFIX hex...], "kind": KIND, "sn": SN}.

`census` reads a capture and prints one JSON line counting its DATA submessages by the writer's
built-in role: {"spdp": N, "participant_message": N, "sedp": N, "sedp_topic": N, "user": N,
"datagrams": N} (SPDP 0x000100c2, ParticipantMessage 0x000200c2, SEDP publications/subscriptions
0x000003c2/0x000004c2, DCPSTopic 0x000002c2; user: a user-defined writer, entity kind 0x02 or
0x03), with "sedp_topic_any": the DCPSTopic writer's DATA, and its HEARTBEATs and ACKNACKs sent to
another participant by unicast.

Everything random comes from --seed (default 29), so a run can be repeated. At the end it prints
one JSON line {"sent": N, "errors": E, "seconds": S, "rate": N / S, "mode": MODE, "seed": SEED,
"datagrams_in_capture": C, "stopped": false}
(errors: sends the kernel refused, e.g. ENOBUFS at full speed) and exits 0. SIGTERM ends a
spray early; the line then also says "stopped": true.
"""

import argparse
import json
import random
import signal
import socket
import struct
import sys
import time

RTPS_HEADER = 20
ETH_P_IP = 0x0800
PACKET_OUTGOING = 4
# A datagram is at most 64 KiB; a generous receive buffer so that no burst is cut.
RECV_BUFFER = 1 << 16
EXTREMES = (0xFFFFFFFF, 0x80000000, 0x00000000, 0x7FFFFFFF)
MODES = ("flip", "splice", "extreme", "truncate")


# ---------------------------------------------------------------------------------------------
# capture


def rtps_datagram(frame: bytes):
    """(dst address bytes, dst port, payload) of an IPv4/UDP frame carrying RTPS, else None.
    `frame` starts at the IP header (an AF_PACKET SOCK_DGRAM socket strips the link layer)."""
    if len(frame) < 20 or frame[0] >> 4 != 4:
        return None
    ihl = (frame[0] & 0x0F) * 4
    total = struct.unpack_from(">H", frame, 2)[0]
    flags_fragment = struct.unpack_from(">H", frame, 6)[0]
    # A fragment (more fragments, or an offset) is not a whole datagram: skip it.
    if frame[9] != socket.IPPROTO_UDP or flags_fragment & 0x3FFF:
        return None
    if total > len(frame) or total < ihl + 8:
        return None
    dst = frame[16:20]
    port = struct.unpack_from(">H", frame, ihl + 2)[0]
    udp_len = struct.unpack_from(">H", frame, ihl + 4)[0]
    payload = frame[ihl + 8 : min(total, ihl + udp_len)]
    if not payload.startswith(b"RTPS"):
        return None
    return dst, port, payload


def capture(args) -> None:
    sock = socket.socket(socket.AF_PACKET, socket.SOCK_DGRAM, socket.htons(ETH_P_IP))
    sock.bind(("lo", 0))
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    print(json.dumps({"listening": True}), flush=True)
    start = time.monotonic()
    deadline = start + args.seconds
    captured = 0
    size = 0
    ports = {}
    with open(args.out, "wb") as out:
        while captured < args.max_datagrams and size < args.max_bytes:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            sock.settimeout(left)
            try:
                frame, address = sock.recvfrom(RECV_BUFFER)
            except socket.timeout:
                break
            if address[2] == PACKET_OUTGOING:
                continue  # the sent copy; the received one follows
            found = rtps_datagram(frame)
            if found is None:
                continue
            dst, port, payload = found
            out.write(dst + struct.pack("<HH", port, len(payload)) + payload)
            captured += 1
            size += len(payload)
            ports[str(port)] = ports.get(str(port), 0) + 1
    summary = {
        "captured": captured,
        "bytes": size,
        "seconds": round(time.monotonic() - start, 3),
        "ports": dict(sorted(ports.items(), key=lambda kv: int(kv[0]))),
    }
    print(json.dumps(summary), flush=True)


# ---------------------------------------------------------------------------------------------
# spray


def read_capture(path: str):
    """The records of a capture file: [((address, port), payload)]."""
    with open(path, "rb") as f:
        data = f.read()
    records = []
    at = 0
    while at + 8 <= len(data):
        dst = socket.inet_ntoa(data[at : at + 4])
        port, length = struct.unpack_from("<HH", data, at + 4)
        payload = data[at + 8 : at + 8 + length]
        if len(payload) < length:
            raise SystemExit(f"{path}: a record at offset {at} is cut short")
        records.append(((dst, port), payload))
        at += 8 + length
    if at != len(data):
        raise SystemExit(f"{path}: {len(data) - at} stray bytes at the end")
    return records


def flip(rng: random.Random, payload: bytes, _records) -> bytes:
    if len(payload) <= RTPS_HEADER:
        return payload
    out = bytearray(payload)
    for _ in range(rng.randint(1, 8)):
        out[rng.randrange(RTPS_HEADER, len(out))] ^= rng.randint(1, 255)
    return bytes(out)


def splice(rng: random.Random, payload: bytes, records) -> bytes:
    other = rng.choice(records)[1]
    head = payload[: rng.randint(min(RTPS_HEADER, len(payload)), len(payload))]
    tail = other[rng.randint(min(RTPS_HEADER, len(other)), len(other)) :]
    return head + tail


def extreme(rng: random.Random, payload: bytes, _records) -> bytes:
    fields = (len(payload) - RTPS_HEADER) // 4
    if fields <= 0:
        return payload
    out = bytearray(payload)
    for _ in range(rng.randint(1, 3)):
        offset = RTPS_HEADER + 4 * rng.randrange(fields)
        struct.pack_into("<I", out, offset, rng.choice(EXTREMES))
    return bytes(out)


def truncate(rng: random.Random, payload: bytes, _records) -> bytes:
    if len(payload) <= 1:
        return payload
    return payload[: rng.randrange(1, len(payload))]


MUTATIONS = {"flip": flip, "splice": splice, "extreme": extreme, "truncate": truncate}


def spray(args) -> None:
    records = read_capture(args.capture)
    if not records:
        raise SystemExit(f"{args.capture}: no datagrams to spray")
    rng = random.Random(args.seed)
    kinds = [MUTATIONS[m] for m in (MODES if args.mode == "mixed" else (args.mode,))]

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    # Multicast leaves through lo only (the namespace's only interface), is never routed
    # (TTL 0) and loops back to the fleet's own multicast sockets.
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
    sock.setblocking(False)

    # SIGTERM ends the spray early but still reports what was sent (a test stops it when a
    # process under test has died).
    stopped = []
    signal.signal(signal.SIGTERM, lambda *_: stopped.append(True))

    sent = 0
    errors = 0
    attempts = 0
    start = time.monotonic()
    end = start + args.seconds
    while attempts < args.max_datagrams and not stopped:
        now = time.monotonic()
        if now >= end:
            break
        if args.rate > 0:
            due = min(int((now - start) * args.rate) + 1, args.max_datagrams)
            if attempts >= due:
                # Until the next datagram is due (never past the end).
                time.sleep(min(start + attempts / args.rate, end) - now)
                continue
            batch = due - attempts
        else:
            batch = min(256, args.max_datagrams - attempts)
        for _ in range(batch):
            address, payload = rng.choice(records)
            datagram = rng.choice(kinds)(rng, payload, records)
            attempts += 1
            try:
                sock.sendto(datagram, address)
                sent += 1
            except OSError:
                errors += 1  # ENOBUFS / EAGAIN at full speed: counted, not fatal
    seconds = time.monotonic() - start
    summary = {
        "sent": sent,
        "errors": errors,
        "seconds": round(seconds, 3),
        "rate": round(sent / seconds, 1) if seconds > 0 else 0.0,
        "mode": args.mode,
        "seed": args.seed,
        "datagrams_in_capture": len(records),
        "stopped": bool(stopped),
    }
    print(json.dumps(summary), flush=True)


# ---------------------------------------------------------------------------------------------
# forge

SPDP_WRITER = bytes.fromhex("000100c2")
DATA = 0x15
PID_SENTINEL = 0x0001
PID_PARTICIPANT_LEASE_DURATION = 0x0002
PID_KEY_HASH = 0x0070
PID_STATUS_INFO = 0x0071
FORGE_KINDS = ("lease0", "goodbye")
# How far above the announcement's a new sequence number is, by kind (each forgery a number
# of its own, so that one does not repeat another's).
NEW_SN_STEP = {"lease0": 1000, "goodbye": 2000}


def spdp_announcements(records):
    """{guid prefix: (destinations, datagram, offset of the DATA submessage)} for the SPDP
    DATA(p) in little-endian datagrams of a capture (rustdds's; the last one per prefix)."""
    found = {}
    for address, payload in records:
        at = RTPS_HEADER
        while at + 4 <= len(payload):
            kind, flags, length = payload[at], payload[at + 1], payload[at + 2 : at + 4]
            if not flags & 1:
                break  # big-endian: not what rustdds sends
            length = struct.unpack("<H", length)[0]
            body = at + 4
            if kind == DATA and payload[body + 8 : body + 12] == SPDP_WRITER:
                prefix = payload[8:20]
                destinations, _, _ = found.get(prefix, (set(), None, None))
                destinations.add(address)
                found[prefix] = (destinations, payload, at)
            if length == 0:
                break
            at = body + length
    return found


def forged(kind: str, new_sn: bool, payload: bytes, at: int) -> bytes:
    """The forged datagram of `kind` from an SPDP announcement whose DATA starts at `at`, under
    its sequence number or (`new_sn`) a new one."""
    flags = payload[at + 1]
    body = at + 4
    to_inline_qos = struct.unpack_from("<H", payload, body + 2)[0]
    sn_high, sn_low = struct.unpack_from("<iI", payload, body + 12)
    if new_sn:
        sn_low += NEW_SN_STEP[kind]
    if kind == "lease0":
        out = bytearray(payload)
        struct.pack_into("<iI", out, body + 12, sn_high, sn_low)
        if flags & 0x02:
            raise SystemExit("forge: an announcement with inline QoS is not expected")
        params = body + 4 + to_inline_qos + 4  # past the encapsulation header
        end = body + struct.unpack_from("<H", payload, at + 2)[0]
        while params + 4 <= end:
            pid, plen = struct.unpack_from("<HH", out, params)
            if pid == PID_SENTINEL:
                break
            if pid == PID_PARTICIPANT_LEASE_DURATION:
                struct.pack_into("<iI", out, params + 4, 0, 0)
                return bytes(out)
            params += 4 + plen
        raise SystemExit("forge: no lease in the announcement")
    key_hash = payload[8:20] + bytes.fromhex("000001c1")
    inline_qos = (
        struct.pack("<HH", PID_KEY_HASH, 16)
        + key_hash
        + struct.pack("<HH", PID_STATUS_INFO, 4)
        + bytes([0, 0, 0, 3])
        + struct.pack("<HH", PID_SENTINEL, 0)
    )
    # extraFlags, octetsToInlineQos (16: reader id, writer id, sequence number), reader id,
    # writer id, sequence number, inline QoS; flags: little-endian and inline QoS, no data.
    data_body = (
        struct.pack("<HH", 0, 16)
        + payload[body + 4 : body + 12]
        + struct.pack("<iI", sn_high, sn_low)
        + inline_qos
    )
    submessage = bytes([DATA, 0x03]) + struct.pack("<H", len(data_body)) + data_body
    return payload[:RTPS_HEADER] + submessage


def forge(args) -> None:
    records = read_capture(args.capture)
    announcements = spdp_announcements(records)
    if not announcements:
        raise SystemExit(f"{args.capture}: no SPDP announcement to forge from")
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
    datagrams = [
        (forged(args.kind, args.sn == "new", payload, at), destinations)
        for destinations, payload, at in announcements.values()
    ]
    sent = 0
    for n in range(args.count):
        if n:
            time.sleep(args.every)
        for datagram, destinations in datagrams:
            for address in sorted(destinations):
                sock.sendto(datagram, address)
                sent += 1
    print(
        json.dumps(
            {
                "forged": sent,
                "participants": sorted(p.hex() for p in announcements),
                "kind": args.kind,
                "sn": args.sn,
            }
        ),
        flush=True,
    )


# ---------------------------------------------------------------------------------------------
# census

WRITER_ROLES = {
    bytes.fromhex("000100c2"): "spdp",
    bytes.fromhex("000200c2"): "participant_message",
    bytes.fromhex("000003c2"): "sedp",
    bytes.fromhex("000004c2"): "sedp",
    bytes.fromhex("000002c2"): "sedp_topic",
}
HEARTBEAT, ACKNACK, INFO_DST = 0x07, 0x06, 0x0E


def census(args) -> None:
    records = read_capture(args.capture)
    counts = {"spdp": 0, "participant_message": 0, "sedp": 0, "user": 0, "datagrams": len(records)}
    counts.update({"spdp_multicast": 0, "spdp_unicast": 0, "sedp_topic": 0, "sedp_topic_any": 0})
    for (dst, _port), payload in records:
        to_group = 224 <= int(dst.split(".")[0]) <= 239
        to_self = False
        at = RTPS_HEADER
        while at + 4 <= len(payload):
            kind, flags = payload[at], payload[at + 1]
            length = struct.unpack("<H" if flags & 1 else ">H", payload[at + 2 : at + 4])[0]
            body = at + 4
            if kind == INFO_DST and body + 12 <= len(payload):
                to_self = payload[body : body + 12] == payload[8:20]
            if kind in (HEARTBEAT, ACKNACK, DATA) and body + 12 <= len(payload):
                # readerId, writerId at body; DATA has 4 more bytes (extraFlags, octetsToInlineQos)
                writer_at = body + 8 if kind == DATA else body + 4
                writer = payload[writer_at : writer_at + 4]
                role = WRITER_ROLES.get(writer)
                # a participant's own DCPSTopic endpoints match each other (local endpoints
                # of one topic do): its HEARTBEATs to the group and ACKNACKs to itself are
                # not a peer's cost
                if role == "sedp_topic" and (kind == DATA or not (to_group or to_self)):
                    counts["sedp_topic_any"] += 1
                if kind == DATA:
                    if role is None and writer[3] in (0x02, 0x03):
                        role = "user"
                    if role is not None:
                        counts[role] += 1
                    if role == "spdp":
                        counts["spdp_multicast" if to_group else "spdp_unicast"] += 1
            if length == 0:
                break
            at = body + length
    print(json.dumps(counts), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    cap = sub.add_parser("capture", help="capture the fleet's RTPS datagrams on lo")
    cap.add_argument("--seconds", type=float, required=True)
    cap.add_argument("--out", required=True)
    cap.add_argument("--max-datagrams", type=int, default=200_000)
    cap.add_argument("--max-bytes", type=int, default=64 << 20)
    spr = sub.add_parser("spray", help="send mutated copies of a capture")
    spr.add_argument("--capture", required=True)
    spr.add_argument("--rate", type=float, required=True, help="datagrams a second, 0: full speed")
    spr.add_argument("--seconds", type=float, required=True)
    spr.add_argument("--mode", choices=MODES + ("mixed",), default="mixed")
    spr.add_argument("--seed", type=int, default=29)
    spr.add_argument("--max-datagrams", type=int, default=50_000_000)
    frg = sub.add_parser("forge", help="send forged SPDP announcements of the captured peers")
    frg.add_argument("--capture", required=True)
    frg.add_argument("--kind", choices=FORGE_KINDS, required=True)
    frg.add_argument("--sn", choices=("same", "new"), required=True)
    frg.add_argument("--count", type=int, default=1)
    frg.add_argument("--every", type=float, default=0.5)
    cen = sub.add_parser("census", help="count a capture's DATA by writer role")
    cen.add_argument("--capture", required=True)
    args = parser.parse_args()
    if args.command == "census":
        census(args)
        return
    if args.command == "forge":
        if not 1 <= args.count <= 100 or not 0 <= args.every <= 10:
            parser.error("--count must be in [1, 100] and --every in [0, 10]")
        forge(args)
        return
    if args.seconds <= 0 or args.seconds > 3600:
        parser.error("--seconds must be in (0, 3600]")
    if args.command == "capture":
        capture(args)
    else:
        if args.rate < 0:
            parser.error("--rate must be >= 0")
        spray(args)


if __name__ == "__main__":
    sys.exit(main())
