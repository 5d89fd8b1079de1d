#!/usr/bin/env python3
"""Seed corpus of hrt_fuzz_udp (runtime/fuzz/README.md, "UDP packets"): valid
packets of each type of docs/udp-protocol.md and a few near misses, written by
examples/udp_device.py's encoder where it has one (so the seeds follow the
documented layout, not the parser under test). Written into the build
directory; nothing binary is committed."""

import argparse
import importlib.util
import struct
from pathlib import Path

HERE = Path(__file__).resolve().parent


def load_client():
    spec = importlib.util.spec_from_file_location("udp_device", HERE.parents[1] / "examples" / "udp_device.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def seeds(c):
    def header(mtype, flags, seq, t):
        return c.HEADER.pack(c.MAGIC, c.VERSION, mtype, flags, seq, 0, t)

    def wrench(seq, answers, w):
        return header(c.TYPE_WRENCH, 0, seq, 0.001 * seq) + c.WRENCH_BODY.pack(answers, 0, *w)

    def objects(seq, poses, total):
        body = b"".join(c.OBJECT.pack(i, 0, *p, *q) for i, p, q in poses)
        return header(c.TYPE_OBJECT_POSES, 0, seq, 0.5) + c.OBJECTS_HEAD.pack(len(poses), total) + body

    pose = c.encode_pose(7, 0.5, (0.1, -0.2, 0.3), (0, 0, 0.6, 0.8), 5, True, True)
    out = {
        "pose.bin": pose,
        "pose_plain.bin": c.encode_pose(0xFFFFFFFF, 12.0, (0, 0, 0), (0, 0, 0, 1)),
        "pose_short.bin": pose[:40],
        "pose_version2.bin": pose[:4] + struct.pack("<H", 2) + pose[6:],
        "pose_zero_quaternion.bin": c.encode_pose(1, 0.0, (0, 0, 0), (0, 0, 0, 0)),
        "wrench.bin": wrench(3, 7, (1.5, -2, 3, 0.25, 0, -0.125)),
        "objects_0.bin": objects(1, [], 0),
        "objects_1.bin": objects(2, [(0, (1, 2, 3), (0, 0, 0, 1))], 1),
        "objects_3.bin": objects(3, [(i, (i, 0, 0), (0, 0, 1, 0)) for i in (0, 2, 4)], 5),
        # The order filter reads the input as 6-byte (sequence, flags, source) records.
        "stream.bin": b"".join(struct.pack("<IBB", s, f, src) for s, f, src in
                               [(5, 0, 0), (6, 0, 0), (6, 0, 0), (4, 0, 0), (0, 1, 0), (0xFFFFFFFF, 0, 0),
                                (0, 0, 0), (9, 0, 1), (1, 0, 0)]),
    }
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--stamp", type=Path)
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for name, data in seeds(load_client()).items():
        (args.out / name).write_bytes(data)
    if args.stamp:
        args.stamp.write_text("ok\n")


if __name__ == "__main__":
    main()
