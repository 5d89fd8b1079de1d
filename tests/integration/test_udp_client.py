"""examples/udp_device.py, the UDP bridge's Python client (docs/udp-protocol.md):
its encoder and decoder against the golden bytes that runtime/tests/test_udp_device.cpp
asserts for the C++ parser, and run_client against a stand-in server on loopback.
(The end-to-end run against `hrt run` lives with `hrt run`'s tests.)"""

import importlib.util
import socket
import struct
import threading
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("udp_device", ROOT / "examples" / "udp_device.py")
udp_device = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(udp_device)

# The same strings as kGoldenPose / kGoldenWrench in runtime/tests/test_udp_device.cpp.
GOLDEN_POSE = (
    "48525455010001010700000000000000000000000000e03f9a9999999999b93f9a9999999999c9bf333333333333d33f"
    "00000000000000000000000000000000333333333333e33f9a9999999999e93f0500000001000000"
)
GOLDEN_WRENCH = (
    "48525455010002000300000000000000000000000000f43f0700000000000000000000000000f83f00000000000000c0"
    "0000000000000840000000000000d03f0000000000000000000000000000c0bf"
)


def test_pose_packet_matches_the_golden_bytes():
    packet = udp_device.encode_pose(7, 0.5, (0.1, -0.2, 0.3), (0, 0, 0.6, 0.8), buttons=5, clutch=True, restart=True)
    assert len(packet) == 88
    assert packet.hex() == GOLDEN_POSE
    # Field offsets of the documented table.
    assert packet[:4] == b"HRTU" and packet[6] == 1 and packet[7] == 1
    assert struct.unpack_from("<d", packet, 24)[0] == 0.1
    assert struct.unpack_from("<d", packet, 72)[0] == 0.8
    assert struct.unpack_from("<I", packet, 80)[0] == 5 and packet[84] == 1


def test_wrench_decoder_reads_the_golden_bytes_and_refuses_bad_ones():
    data = bytes.fromhex(GOLDEN_WRENCH)
    w = udp_device.decode_wrench(data)
    assert w == {"flags": 0, "sequence": 3, "t": 1.25, "answers": 7,
                 "force": (1.5, -2.0, 3.0), "torque": (0.25, 0.0, -0.125)}
    assert udp_device.decode_wrench(data[:-1]) is None  # size
    assert udp_device.decode_wrench(b"X" + data[1:]) is None  # magic
    assert udp_device.decode_wrench(data[:4] + b"\x02" + data[5:]) is None  # version
    assert udp_device.decode_wrench(bytes.fromhex(GOLDEN_POSE)) is None  # type
    nan = data[:32] + struct.pack("<d", float("nan")) + data[40:]
    assert udp_device.decode_wrench(nan) is None


def test_object_poses_decoder():
    head = struct.pack("<4sHBBIId", b"HRTU", 1, 3, 1, 9, 0, 2.0) + struct.pack("<II", 2, 3)
    objs = struct.pack("<II7d", 0, 0, 1, 2, 3, 0, 0, 0, 1) + struct.pack("<II7d", 2, 0, 4, 5, 6, 1, 0, 0, 0)
    d = udp_device.decode_object_poses(head + objs)
    assert d["total"] == 3 and d["t"] == 2.0
    assert d["objects"] == [(0, (1.0, 2.0, 3.0), (0.0, 0.0, 0.0, 1.0)), (2, (4.0, 5.0, 6.0), (1.0, 0.0, 0.0, 0.0))]
    assert udp_device.decode_object_poses(head + objs[:-8]) is None
    bad_index = head[:-4] + struct.pack("<I", 2) + objs  # total 2: index 2 out of range
    assert udp_device.decode_object_poses(bad_index) is None


def test_run_client_sends_in_order_and_collects_the_answers():
    """A stand-in for hrt: answers each pose with a wrench whose force x is the pose's x."""
    server = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    server.bind(("127.0.0.1", 0))
    server.settimeout(2.0)
    port = server.getsockname()[1]
    seen = []

    def serve():
        for _ in range(20):
            try:
                data, addr = server.recvfrom(2048)
            except socket.timeout:
                return
            magic, version, mtype, flags, seq, _, t = struct.unpack_from("<4sHBBIId", data)
            x = struct.unpack_from("<d", data, 24)[0]
            seen.append((len(data), mtype, flags, seq, t, x))
            reply = struct.pack("<4sHBBIId", b"HRTU", 1, 2, 0, seq, 0, t) + struct.pack("<II6d", seq, 0, x, 0, 0, 0, 0, 0)
            server.sendto(reply, addr)

    thread = threading.Thread(target=serve)
    thread.start()
    poses = udp_device.path_poses("line", duration=0.02, rate=1000.0, radius=0.01)
    try:
        wrenches = udp_device.run_client("127.0.0.1", port, poses, rate=1000.0, linger=0.3)
    finally:
        thread.join()
        server.close()
    assert len(poses) == 20
    assert [s[3] for s in seen] == list(range(20))
    assert all(s[0] == 88 and s[1] == 1 for s in seen)
    assert [s[2] for s in seen] == [1] + [0] * 19  # restart flag on the first packet only
    assert [w["answers"] for w in wrenches] == list(range(20))
    for w, (t, pos, _) in zip(wrenches, poses):
        assert w["force"][0] == pos[0] and w["t"] == t
