"""hbake: bake high-resolution triangle meshes into haptic bundles.

Library first: ``hbake.bake(input, output, settings)`` does the work (see
``hbake.routes.pipeline``); ``hbake.cli`` only turns command-line options into a
``BakeSettings``. The bundle format is specified in docs/bundle-format.md.
"""
from __future__ import annotations

from importlib import metadata as _metadata

try:
    __version__ = _metadata.version("hbake")
except _metadata.PackageNotFoundError:  # running from a source tree without install
    __version__ = "0.1.0"

from hbake.settings import BakeSettings  # noqa: E402
from hbake.routes.pipeline import bake  # noqa: E402

__all__ = ["bake", "BakeSettings", "__version__"]
