#!/usr/bin/env python3
"""Seed corpus of hrt_fuzz_bundle: the golden bundles packed into its container.

Usage: make_corpus.py --golden tests/golden --out build/fuzz/fuzz/seed_corpus

Every tests/golden/*.hbundle, tests/golden/format-1.2/*.hbundle and
tests/golden/corrupt/*.hbundle becomes a few
inputs (flags x pose, see VARIANTS); the container format is documented in
fuzz_bundle.cpp and runtime/fuzz/README.md:

    u32 flags | u8 pose[8] | 4 x (u32 length, bytes)   (little-endian)
    sections: manifest.json, coarse.ply, atlas.exr, pieces.ply
    length 0xFFFFFFFF = file absent

The output directory is replaced; file names are stable, so the same golden
bundles give the same corpus. Also usable by hand: --pack BUNDLE OUT packs one
bundle directory (--flags, --pose as 8 comma-separated bytes).
"""
import argparse
import pathlib
import shutil
import struct
import sys

NAMES = ("manifest.json", "coarse.ply", "atlas.exr", "pieces.ply")
ABSENT = 0xFFFFFFFF

# Pose bytes: p0..p2 offset (128 = 0), p3..p6 quaternion x y z w (128 = 0), p7 bit 0 = two frames.
IDENTITY = (128, 128, 128, 255)
DEEP = (128, 128, 128) + IDENTITY + (0,)            # A's bbox centre on B's: deep overlap
GRAZE = (128, 128, 166) + IDENTITY + (1,)           # A above B by 0.3 (rA + rB), two frames
TILTED = (140, 120, 160) + (160, 100, 140, 230) + (1,)  # off-axis, rotated, two frames

# (suffix, flags, pose) per bundle; the corrupt bundles get the first two only.
VARIANTS = (
    ("h0-deep", 0x0, DEEP),         # hashes off: the files as they are
    ("h1-graze", 0x1, GRAZE),       # hashes on (the harness patches the manifest)
    ("h1-golden-tilted", 0x5, TILTED),  # B = golden pebble
    ("h1-shortcut-deep", 0x9, DEEP),    # Sec. 5.2 shortcut
    ("noinv", 0x2, DEEP),           # invariant checks off: load and lookups only
)


def pack(bundle: pathlib.Path, flags: int, pose) -> bytes:
    out = bytearray(struct.pack("<I", flags) + bytes(pose))
    for name in NAMES:
        f = bundle / name
        if f.is_file():
            data = f.read_bytes()
            out += struct.pack("<I", len(data)) + data
        else:
            out += struct.pack("<I", ABSENT)
    return bytes(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--golden", type=pathlib.Path, help="tests/golden")
    ap.add_argument("--out", type=pathlib.Path, help="corpus directory to (re)write")
    ap.add_argument("--stamp", type=pathlib.Path, help="file touched when done (for the build)")
    ap.add_argument("--pack", nargs=2, metavar=("BUNDLE", "OUT"), help="pack one bundle directory into OUT")
    ap.add_argument("--flags", type=lambda s: int(s, 0), default=0)
    ap.add_argument("--pose", default=",".join(map(str, DEEP)))
    a = ap.parse_args()

    if a.pack:
        pose = [int(x) for x in a.pose.split(",")]
        if len(pose) != 8 or not all(0 <= x <= 255 for x in pose):
            ap.error("--pose needs 8 bytes")
        pathlib.Path(a.pack[1]).write_bytes(pack(pathlib.Path(a.pack[0]), a.flags, pose))
        return 0
    if not a.golden or not a.out:
        ap.error("--golden and --out are required (or --pack)")

    # the current format's bundles and the one kept in format 1.2 (pieces.ply's
    # map as one list per piece), so both layouts of pieces.ply are seeds
    good = sorted(a.golden.glob("*.hbundle")) + sorted((a.golden / "format-1.2").glob("*.hbundle"))
    bad = sorted((a.golden / "corrupt").glob("*.hbundle"))
    if not good:
        print(f"make_corpus.py: no bundle in {a.golden}", file=sys.stderr)
        return 1
    if a.out.exists():
        shutil.rmtree(a.out)
    a.out.mkdir(parents=True)
    n = 0
    for group, bundles, variants in (("golden", good, VARIANTS), ("corrupt", bad, VARIANTS[:2])):
        for b in bundles:
            for suffix, flags, pose in variants:
                (a.out / f"{group}-{b.stem}-{suffix}").write_bytes(pack(b, flags, pose))
                n += 1
    print(f"make_corpus.py: {n} seeds in {a.out}")
    if a.stamp:
        a.stamp.touch()
    return 0


if __name__ == "__main__":
    sys.exit(main())
