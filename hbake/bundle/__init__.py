"""The haptic bundle (``.hbundle``): the reference implementation of docs/bundle-format.md.

The C++ loader in ``runtime/src/io/`` must agree with it; both are checked against the
golden bundles in ``tests/golden/``. One module per concern, as in the runtime:

* format: the constants (version, file names, limits) and the data types
  (:class:`BundleData`, :class:`Bundle`, :class:`Problem`);
* manifest: the manifest's canonical bytes, its JSON schema and the loader's own rules;
* ply, exr: the three files' readers and writers (byte-deterministic);
* lookup: UV to texel and the bilinear atlas lookup of the spec;
* write: :func:`write_bundle`, atomic (a temporary sibling directory, then
  ``os.rename``) and validated before it is published;
* validate (with pieces and uv_coverage): :func:`validate_bundle` returns one
  :class:`Problem` per issue, each with the spec's error class (``io``, ``version``,
  ``schema``, ``hash``, ``mesh``, ``atlas``, ``pieces``); :func:`read_bundle` raises the
  first as a :class:`~hbake.errors.BundleError`;
* surface_coverage: where the mesh heights' guarantee holds (``hbake inspect``).

What this package exports below is its public API; the modules' other names may change.
"""
from hbake.bundle.exr import read_atlas_exr, write_atlas_exr
from hbake.bundle.format import (
                                 ERROR_CLASSES,
                                 FILE_NAMES,
                                 FORMAT_MAJOR,
                                 FORMAT_NAME,
                                 FORMAT_VERSION,
                                 PIECES_TABLE_MINOR,
                                 Bundle,
                                 BundleData,
                                 Problem,
                                 convexity_tolerance,
)
from hbake.bundle.lookup import atlas_lookup, texel_coords
from hbake.bundle.manifest import load_schema, manifest_bytes, sha256_file
from hbake.bundle.pieces import MAX_PIECE_FACES, MAX_PIECE_VERTICES
from hbake.bundle.ply import (
                                 pieces_layout_is_table,
                                 read_coarse_ply,
                                 read_pieces_ply,
                                 write_coarse_ply,
                                 write_pieces_ply,
)
from hbake.bundle.validate import (
                                 check_bundle,
                                 check_bundle_data,
                                 read_bundle,
                                 validate_bundle,
)
from hbake.bundle.write import remove_stale_temporaries, write_bundle
from hbake.errors import BundleError

__all__ = [
    "FORMAT_NAME", "FORMAT_VERSION", "FORMAT_MAJOR", "FILE_NAMES", "ERROR_CLASSES",
    "PIECES_TABLE_MINOR", "pieces_layout_is_table", "MAX_PIECE_VERTICES", "MAX_PIECE_FACES",
    "BundleData", "Bundle", "Problem", "BundleError",
    "write_bundle", "remove_stale_temporaries", "read_bundle", "validate_bundle", "check_bundle",
    "check_bundle_data", "atlas_lookup", "texel_coords",
    "load_schema", "manifest_bytes", "sha256_file",
    "write_coarse_ply", "read_coarse_ply", "write_pieces_ply", "read_pieces_ply",
    "write_atlas_exr", "read_atlas_exr", "convexity_tolerance",
]
