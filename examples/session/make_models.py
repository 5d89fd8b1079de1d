"""Models of the worked session (examples/session/run.sh): a 4 mm ball tip (a smooth
sphere, 5,120 triangles, meters) written to OUT/ball.ply, and the procedural grating
(`hbake generate grating`: 60 x 60 mm, a sinusoidal grating of 5 mm wavelength and
0.5 mm amplitude turned 23 degrees) to OUT/grating.ply."""
import sys
from pathlib import Path

import trimesh

from hbake.lab import procedural as P

out = Path(sys.argv[1])
out.mkdir(parents=True, exist_ok=True)
ball = trimesh.creation.icosphere(subdivisions=4, radius=4e-3)
trimesh.Trimesh(ball.vertices, ball.faces, process=False).export(out / "ball.ply")
P.generate("grating", out / "grating.ply")
print(f"wrote {out / 'ball.ply'} and {out / 'grating.ply'}")
