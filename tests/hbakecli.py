"""The `hbake` command as a child process, and convex hulls of sphere points, for the
reliability tests."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np


def _hbake() -> list[str]:
    script = Path(sys.executable).with_name("hbake")
    if script.exists():
        return [str(script)]
    return [sys.executable, "-c", "from hbake.cli import main; main()"]


def _sphere_hull(n: int, rng, centre, radius):
    from hbake.stages.mass import convex_hull_mesh
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = (np.asarray(centre) + radius * d).astype(np.float32).astype(np.float64)
    hv, hf = convex_hull_mesh(pts)
    return hv, hf.astype(np.uint32)
