"""hbake: bake high-resolution triangle meshes into haptic bundles.

Library first: ``hbake.bake(input, output, settings)`` does the work; the ``hbake``
command (``hbake.cli``) only turns command-line options into a ``BakeSettings``. The
bundle format is specified in docs/bundle-format.md; this package's public API is
documented in docs/reference/hbake-api.md and is what ``__all__`` lists: baking,
reading, validating and writing bundles, and the error classes. The subpackages
(``stages``, ``routes``, ``bundle``, ``batch``, ``lab``, ``viz``, ``cli``) hold the rest.
"""
from __future__ import annotations

from importlib import metadata as _metadata

try:
    __version__ = _metadata.version("hbake")
except _metadata.PackageNotFoundError:  # running from a source tree without install
    __version__ = "0.1.0"

from hbake.bundle import (  # noqa: E402
    Bundle,
    BundleData,
    Problem,
    atlas_lookup,
    check_bundle,
    read_bundle,
    validate_bundle,
    write_bundle,
)
from hbake.errors import BakeFailedError, BundleError, ConfigError, HbakeError, InputInvalidError  # noqa: E402
from hbake.routes.pipeline import bake  # noqa: E402
from hbake.settings import BakeSettings  # noqa: E402

__all__ = [
    "bake", "BakeSettings",
    "read_bundle", "validate_bundle", "check_bundle", "write_bundle", "atlas_lookup",
    "Bundle", "BundleData", "Problem",
    "HbakeError", "BundleError", "BakeFailedError", "ConfigError", "InputInvalidError",
    "__version__",
]
