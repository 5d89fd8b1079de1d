#!/usr/bin/env python3
"""The benchmark models of Table 1, made and baked into OUT.

    .venv/bin/python examples/experiments/models.py OUT [NAME ...] [--force]

For each model: the full-resolution mesh OUT/NAME.ply, then the bundle
OUT/NAME.hbundle (`hbake bake`), and OUT/NAME.bake.json (`--report`: triangle
counts, pieces, bake time). Existing bundles are kept unless --force. Models:

  block   hbake generate ridged_block: 65,536 triangles, 12 sinusoidal ridges (5 mm, 0.5 mm)
  gear    hbake generate ridged_gear: 25,600 triangles, 50 ridges along the rim (5 mm, 0.5 mm)
  torus   hbake generate wrinkled_torus: 128,000 triangles, helical wrinkles
  hammer  ../shared/models/hammer_scan.obj (a raw scan; units taken as inches: a 21 cm hammer)
          with a knurled handle: hbake texture --pattern knurl, cylindrical about the handle
  cad     ../shared/models/fandisk.obj (units taken as cm: 48 x 52 x 27 mm) with a machined
          finish: hbake texture --pattern grooves, 1.92 mm apart at 45 degrees, 0.08 mm deep
  file    hbake generate rasp: 285,152 triangles, cross-cut teeth (the paper's file)

The shared models are read in place (never copied into the repository). The same
code makes the same meshes every time (hbake texture and hbake generate are
deterministic).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
# The shared models' folder: $HBAKE_MODELS, else ../shared/models beside the repository.
SHARED = Path(os.environ["HBAKE_MODELS"]) if os.environ.get("HBAKE_MODELS") else REPO.parent / "shared" / "models"
HBAKE = str(REPO / ".venv" / "bin" / "hbake")

#: name -> (how the full mesh is made, --units of the bake, the paper's Table 1 row:
#: full triangles, low-res triangles, low-res pieces)
MODELS = {
    "block": (["generate", "ridged_block"], "m", (65536, 16, 1)),
    "gear": (["generate", "ridged_gear"], "m", (25600, 1600, 1)),
    "hammer": (["texture", str(SHARED / "hammer_scan.obj"), "--pattern", "knurl",
                "--mapping", "cylindrical", "--axis", "0,0,1", "--origin", "-0.08,0,0",
                # The handle (the head is above z = 3.3 in the file's units).
                "--region", "box:-0.7,-0.5,-3.9,0.6,0.5,3.2",
                "--amplitude", "0.005", "--wavelength", "0.135",
                # The raw scan's normals are noisy: 12 rounds keep the knurl from folding faces.
                "--normal-smoothing", "12"], "in", (433152, 518, 210)),
    "cad": (["texture", str(SHARED / "fandisk.obj"), "--pattern", "grooves",
             "--amplitude", "0.008", "--wavelength", "0.192", "--direction", "1,1,0"],
            "cm", (658432, 720, 390)),
    "file": (["generate", "rasp"], "m", (285824, 632, 113)),
    "torus": (["generate", "wrinkled_torus"], "m", (128000, 532, 114)),
}


def make(name: str, out: Path) -> Path:
    how, _, _ = MODELS[name]
    mesh = out / f"{name}.ply"
    if how[0] == "generate":
        cmd = [HBAKE, *how, str(mesh)]
    else:
        if not Path(how[1]).is_file():
            sys.exit(f"models.py: {how[1]} is missing: set HBAKE_MODELS to the folder of the shared models "
                     f"(default: ../shared/models beside the repository)")
        cmd = [HBAKE, how[0], how[1], "-o", str(mesh), "-f", "-q", *how[2:]]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return mesh


def bake(name: str, out: Path, force: bool = False) -> dict:
    """Make and bake `name` unless its bundle exists; returns its report's figures."""
    bundle = out / f"{name}.hbundle"
    report = out / f"{name}.bake.json"
    if force or not (bundle / "manifest.json").is_file() or not report.is_file():
        t0 = time.perf_counter()
        mesh = make(name, out)
        t_make = time.perf_counter() - t0
        subprocess.run([HBAKE, "bake", str(mesh), "-o", str(bundle), "--units", MODELS[name][1], "-f", "-q",
                        "--report", str(report)], check=True)
        data = json.loads(report.read_text())
        data["make_seconds"] = t_make
        report.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n")
    data = json.loads(report.read_text())
    m = data["manifest"]
    return {"name": name, "bundle": bundle, "full": m["source"]["triangles"],
            "coarse": m["coarse"]["triangles"], "pieces": m["pieces"]["count"],
            "bake_s": data["total_seconds"], "make_s": data.get("make_seconds", 0.0),
            "texel": m["atlas"]["texel_size"], "paper": MODELS[name][2]}


def main(argv):
    args = [a for a in argv if not a.startswith("-")]
    force = "--force" in argv
    if not args:
        sys.exit(__doc__)
    out = Path(args[0])
    out.mkdir(parents=True, exist_ok=True)
    for name in args[1:] or list(MODELS):
        if name not in MODELS:
            sys.exit(f"models.py: unknown model {name!r} (known: {', '.join(MODELS)})")
        r = bake(name, out, force)
        print(f"{r['bundle']}: {r['full']:,} -> {r['coarse']:,} triangles, {r['pieces']} pieces, "
              f"bake {r['bake_s']:.1f} s", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
