#!/usr/bin/env python3
"""A UDP device client for `hrt run` with `[device] type = "udp"` (docs/udp-protocol.md).

Sends the pose of a virtual device handle along a simple path at a fixed rate
and receives the wrenches hrt sends back. Standard library only.

    python3 examples/udp_device.py --port 47800 --rate 1000 --duration 5 --path circle

As a module (tests, scripts):

    import udp_device
    packet = udp_device.encode_pose(seq, t, (x, y, z), (qx, qy, qz, qw))
    wrench = udp_device.decode_wrench(data)           # None if not a valid wrench packet
    wrenches = udp_device.run_client("127.0.0.1", 47800, poses, rate=1000.0)
"""

import argparse
import math
import socket
import struct
import sys
import time

MAGIC = b"HRTU"
VERSION = 1
TYPE_POSE, TYPE_WRENCH, TYPE_OBJECT_POSES = 1, 2, 3
FLAG_RESTART = 0x01

# Little-endian, no padding: magic, version, type, flags, sequence, reserved, timestamp.
HEADER = struct.Struct("<4sHBBIId")  # 24 bytes
POSE_BODY = struct.Struct("<7dIB3x")  # position, quaternion x y z w, buttons, clutch: 64 bytes
WRENCH_BODY = struct.Struct("<II6d")  # answers, reserved, force, torque: 56 bytes
OBJECTS_HEAD = struct.Struct("<II")  # count, total
OBJECT = struct.Struct("<II7d")  # index, reserved, position, quaternion: 64 bytes
MAX_OBJECTS_PER_PACKET = 1000


def encode_pose(seq, t, position, quaternion=(0.0, 0.0, 0.0, 1.0), buttons=0, clutch=False, restart=False):
    """The 88-byte pose packet (sequence `seq` mod 2^32, timestamp `t` in s)."""
    header = HEADER.pack(MAGIC, VERSION, TYPE_POSE, FLAG_RESTART if restart else 0, seq & 0xFFFFFFFF, 0, float(t))
    return header + POSE_BODY.pack(*map(float, position), *map(float, quaternion), buttons, 1 if clutch else 0)


def _header(data, expected_type):
    if len(data) < HEADER.size:
        return None
    magic, version, mtype, flags, seq, _, t = HEADER.unpack_from(data)
    if magic != MAGIC or version != VERSION or mtype != expected_type or not math.isfinite(t):
        return None
    return {"flags": flags, "sequence": seq, "t": t}


def decode_wrench(data):
    """A dict (sequence, t, flags, answers, force, torque) or None when `data` is no valid wrench packet."""
    h = _header(data, TYPE_WRENCH)
    if h is None or len(data) != HEADER.size + WRENCH_BODY.size:
        return None
    answers, _, *w = WRENCH_BODY.unpack_from(data, HEADER.size)
    if not all(math.isfinite(x) for x in w):
        return None
    return dict(h, answers=answers, force=tuple(w[:3]), torque=tuple(w[3:]))


def decode_object_poses(data):
    """A dict (sequence, t, flags, total, objects: [(index, position, quaternion)]) or None."""
    h = _header(data, TYPE_OBJECT_POSES)
    if h is None or len(data) < HEADER.size + OBJECTS_HEAD.size:
        return None
    count, total = OBJECTS_HEAD.unpack_from(data, HEADER.size)
    if count > MAX_OBJECTS_PER_PACKET or len(data) != HEADER.size + OBJECTS_HEAD.size + OBJECT.size * count:
        return None
    objects = []
    for k in range(count):
        index, _, *v = OBJECT.unpack_from(data, HEADER.size + OBJECTS_HEAD.size + OBJECT.size * k)
        if index >= total or not all(math.isfinite(x) for x in v):
            return None
        objects.append((index, tuple(v[:3]), tuple(v[3:])))
    return dict(h, total=total, objects=objects)


def path_poses(path="circle", duration=5.0, rate=1000.0, radius=0.02, height=0.0):
    """(t, position, quaternion) samples: a circle of `radius` in the xy plane
    (one turn per 2 s, the handle turning with it about z), or a line along x
    (back and forth over 2 radius, period 2 s), or a still pose."""
    n = max(1, int(round(duration * rate)))
    out = []
    for i in range(n):
        t = i / rate
        a = math.pi * t  # rad; one turn per 2 s
        if path == "circle":
            pos = (radius * math.cos(a), radius * math.sin(a), height)
            quat = (0.0, 0.0, math.sin(a / 2), math.cos(a / 2))
        elif path == "line":
            pos = (radius * math.sin(a), 0.0, height)
            quat = (0.0, 0.0, 0.0, 1.0)
        elif path == "still":
            pos, quat = (0.0, 0.0, height), (0.0, 0.0, 0.0, 1.0)
        else:
            raise ValueError(f"unknown path {path!r} (circle, line, still)")
        out.append((t, pos, quat))
    return out


def drain_wrenches(sock, out: list) -> None:
    """Reads every datagram waiting on the non-blocking socket `sock` and appends the
    valid wrench packets to `out` (decode_wrench dicts); others are ignored."""
    while True:
        try:
            data = sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except ConnectionRefusedError:  # an ICMP error from an earlier send: nobody listening yet
            continue
        w = decode_wrench(data)
        if w is not None:
            out.append(w)


def run_client(host, port, poses, rate=1000.0, linger=0.2, bind=("127.0.0.1", 0), on_wrench=None):
    """Sends `poses` ((t, position, quaternion) or (t, position, quaternion,
    buttons, clutch) tuples) to host:port at `rate` Hz (absolute deadlines),
    collects the wrench packets that come back meanwhile and for `linger`
    seconds after the last pose, and returns them (decode_wrench dicts, in
    arrival order). The first packet carries the restart flag."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(bind)
    sock.setblocking(False)
    wrenches = []

    def drain():
        n = len(wrenches)
        drain_wrenches(sock, wrenches)
        if on_wrench:
            for w in wrenches[n:]:
                on_wrench(w)

    try:
        period = 1.0 / rate
        start = time.monotonic()
        for seq, sample in enumerate(poses):
            t, pos, quat = sample[:3]
            buttons, clutch = (sample[3], sample[4]) if len(sample) >= 5 else (0, False)
            packet = encode_pose(seq, t, pos, quat, buttons, clutch, restart=(seq == 0))
            try:
                sock.sendto(packet, (host, port))
            except ConnectionRefusedError:
                pass
            drain()
            delay = start + (seq + 1) * period - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        end = time.monotonic() + linger
        while time.monotonic() < end:
            drain()
            time.sleep(0.001)
        drain()
    finally:
        sock.close()
    return wrenches


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--host", default="127.0.0.1", help="hrt's address (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=47800, help="hrt's UDP port (default 47800)")
    p.add_argument("--rate", type=float, default=1000.0, help="pose packets per second (default 1000)")
    p.add_argument("--duration", type=float, default=5.0, help="seconds (default 5)")
    p.add_argument("--path", choices=["circle", "line", "still"], default="circle")
    p.add_argument("--radius", type=float, default=0.02, help="m (default 0.02)")
    p.add_argument("--height", type=float, default=0.0, help="z of the path, m (default 0)")
    p.add_argument("--every", type=int, default=100, help="print every N-th wrench (default 100; 0: none)")
    args = p.parse_args(argv)

    count = [0]

    def show(w):
        count[0] += 1
        if args.every and count[0] % args.every == 1:
            f, m = w["force"], w["torque"]
            print(f"t={w['t']:.3f} s answers={w['answers']} force=({f[0]:+.3f}, {f[1]:+.3f}, {f[2]:+.3f}) N "
                  f"torque=({m[0]:+.4f}, {m[1]:+.4f}, {m[2]:+.4f}) N m", flush=True)

    poses = path_poses(args.path, args.duration, args.rate, args.radius, args.height)
    wrenches = run_client(args.host, args.port, poses, args.rate, on_wrench=show)
    print(f"sent {len(poses)} poses, received {len(wrenches)} wrenches", file=sys.stderr)
    return 0 if wrenches else 1


if __name__ == "__main__":
    sys.exit(main())
