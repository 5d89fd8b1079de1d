"""The cage route's own steps (``method = "cage"``): the convex decomposition started in a
thread beside the atlas, and the parameterize and bake stages on the simplified mesh."""
from __future__ import annotations
import threading
import time
from hbake.stages.atlas import bake_atlas
from hbake.stages.decompose import decompose
from hbake.stages.parameterize import parameterize
from hbake.stages.simplify import cap_holes

#: Share of texels whose rays found no surface above which the bake warns.
FALLBACK_WARN_FRACTION = 0.01


def start_decompose(coarse, settings, warn):
    """The coarse mesh's solid (holes capped where open) and the CoACD thread."""
    # An open coarse mesh is decomposed (and weighed) with its holes capped.
    solid = (coarse.vertices, coarse.faces) if coarse.closed else cap_holes(coarse.vertices, coarse.faces)
    if not coarse.closed and solid is not None:
        warn(f"the coarse mesh is open: its holes were capped ({len(solid[1]) - len(coarse.faces)} "
             f"triangles, not stored) for the convex pieces and the mass properties")
    elif not coarse.closed:
        warn("the coarse mesh is open and its holes could not be capped: CoACD remeshes it "
             "(slower, pieces approximate a shell) and mass properties fall back further")
    # CoACD needs only the coarse mesh and releases the GIL, so it runs in a thread while
    # xatlas and embree work: on the 650k CAD part that hides most of its 6.5 s. Its
    # warnings are collected and emitted after it, so their order stays deterministic.
    decomposer = _Background(lambda: decompose(coarse.vertices, coarse.faces, settings.decompose,
                                               seed=settings.seed, solid=solid))
    decomposer.start()
    return solid, decomposer


def cage_atlas(full, coarse, settings, progress, warn):
    """The cage route's parameterize and bake stages."""
    with progress.stage("parameterize"):
        param = parameterize(coarse.vertices, coarse.faces, settings.parameterize)
    with progress.stage("bake", total=1.0) as update:
        baked = bake_atlas(coarse.vertices, coarse.faces, param.uvs, param.width, param.height,
                           full.vertices, full.faces, settings.cage, settings.atlas,
                           progress=update)
        covered = int(baked.covered.sum())
        if baked.fallbacks > FALLBACK_WARN_FRACTION * covered:
            warn(f"{baked.fallbacks} of {covered} covered texels ({100 * baked.fallbacks / covered:.1f}%) "
                 f"found no surface along the normal within {settings.cage.max_ray_distance:g} of the "
                 f"bbox diagonal and use the closest point instead")
    return param, baked


class _Background:
    """Runs ``fn`` in a daemon thread; ``result()`` waits and returns its value or raises
    its exception. Daemon: a Ctrl-C in the main thread ends the process without waiting
    for it (nothing of it is written anywhere)."""

    def __init__(self, fn):
        self._fn = fn
        self._value = None
        self._error: BaseException | None = None
        self.seconds = 0.0
        self._thread = threading.Thread(target=self._run, name="hbake-decompose", daemon=True)

    def _run(self):
        t0 = time.perf_counter()
        try:
            self._value = self._fn()
        except BaseException as exc:      # handed to the main thread by result()
            self._error = exc
        finally:
            self.seconds = time.perf_counter() - t0

    def start(self):
        self._thread.start()

    def result(self):
        self._thread.join()
        if self._error is not None:
            raise self._error
        return self._value
