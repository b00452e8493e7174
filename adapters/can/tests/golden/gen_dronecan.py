#!/usr/bin/env python3
"""Reference DroneCAN frames for rove-can's golden tests (src/dronecan.rs, `golden` tests).

Encodes messages with pydronecan (`python3 -m pip install dronecan`; the values in the Rust
tests were produced with dronecan 1.0.27) and prints each transfer's frames as 29-bit CAN id
and data bytes, ready to paste into Rust. No CAN bus is needed: `Transfer.to_frames()` is the
library's own transport layer (tail byte, toggle, multi-frame CRC seeded from the DSDL data type
signature).

Run: python3 adapters/can/tests/golden/gen_dronecan.py
"""
import dronecan
from dronecan import transport

NODE_ID = 100
PRIORITY = 16


def show(name, msg, transfer_id, priority=PRIORITY):
    t = transport.Transfer(transfer_id=transfer_id, source_node_id=NODE_ID, payload=msg,
                           transfer_priority=priority)
    dtype = transport.get_dronecan_data_type(msg)
    print("// %s: dtid %d, signature 0x%016x, base CRC 0x%04x, payload %s"
          % (name, dtype.default_dtid, dtype.get_data_type_signature(), dtype.base_crc,
             bytes(t.payload).hex()))
    for f in t.to_frames():
        print("(0x%08x, [%s])," % (f.message_id, ", ".join("0x%02x" % b for b in f.bytes)))
    print()


def array_command(values):
    cmds = []
    for i, v in enumerate(values):
        cmds.append(dronecan.uavcan.equipment.actuator.Command(
            actuator_id=i, command_type=0, command_value=v))
    return dronecan.uavcan.equipment.actuator.ArrayCommand(commands=cmds)


print("# pydronecan", dronecan.__version__ if hasattr(dronecan, "__version__") else "?")
show("ArrayCommand 1 servo [0.5]", array_command([0.5]), 0)
show("ArrayCommand 3 servos [-1.0, 0.3333, 0.25]", array_command([-1.0, 0.3333, 0.25]), 5)
show("RawCommand [0, 8191, -8192, 1234]",
     dronecan.uavcan.equipment.esc.RawCommand(cmd=[0, 8191, -8192, 1234]), 7)
show("RawCommand [100, -100, 4000, -4000, 0, 8191]",
     dronecan.uavcan.equipment.esc.RawCommand(cmd=[100, -100, 4000, -4000, 0, 8191]), 30)
show("NodeStatus uptime 12345 s, OK, OPERATIONAL",
     dronecan.uavcan.protocol.NodeStatus(uptime_sec=12345, health=0, mode=0, sub_mode=0,
                                         vendor_specific_status_code=0), 31, priority=24)
show("NodeStatus uptime 70000 s, WARNING, OPERATIONAL, vendor 0xBEEF",
     dronecan.uavcan.protocol.NodeStatus(uptime_sec=70000, health=1, mode=0, sub_mode=0,
                                         vendor_specific_status_code=0xBEEF), 2, priority=24)
