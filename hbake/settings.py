"""Typed settings of ``hbake bake``.

One frozen dataclass per stage, grouped in ``BakeSettings``. The fields map one to
one onto the TOML files in ``configs/`` (top-level keys ``method`` and ``seed``, one
table per stage), onto ``--set SECTION.KEY=VALUE`` on the command line, and onto
``manifest["settings"]`` (``BakeSettings.to_dict()``). Every field documents its
default (taken from ``hbake.constants``) in its metadata; ``describe()`` lists them.

Route-specific options live in a table named after the route: ``[cage]`` holds the
options of the cage bake (``method = "cage"``), ``[preserve]`` those of the
parameterization-preserving route (``method = "pp"``, alias ``"preserve"``; hbake/routes/preserve.py)
and of ``method = "auto"``, while the shared stages (load, simplify, parameterize, atlas,
decompose, quality) keep theirs.
"""
from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hbake import constants as C
from hbake.errors import ConfigError
from hbake.fileio import read_regular

#: A settings file is a few hundred bytes; this only keeps a wrong path from filling memory.
MAX_CONFIG_BYTES = 1 << 20


def _opt(default: Any, doc: str, *, choices: tuple | None = None,
         lo: float | None = None, hi: float | None = None, lo_open: bool = False):
    """A settings field with its documentation and allowed range."""
    return field(default=default, metadata={
        "doc": doc, "choices": choices, "lo": lo, "hi": hi, "lo_open": lo_open})


class _Validated:
    """Checks type and range of every scalar field at construction (frozen dataclasses)."""

    def __post_init__(self):
        for f in dataclasses.fields(self):
            if f.name in SECTIONS:
                continue
            value = _coerce(f, getattr(self, f.name), f"{type(self).__name__}.{f.name}")
            object.__setattr__(self, f.name, value)


@dataclass(frozen=True)
class LoadSettings(_Validated):
    units: str = _opt("auto", "Unit of the input coordinates. 'auto' takes the unit the "
                      "format fixes (glTF: m) and otherwise assumes meters with a loud "
                      "warning that shows the bounding box.",
                      choices=("auto", "mm", "cm", "m", "in"))


@dataclass(frozen=True)
class SimplifySettings(_Validated):
    target_faces: int = _opt(C.DEFAULT_TARGET_FACES, "Triangle count of the coarse mesh "
                             "(the paper's Table 1: 518-720 for 285k-658k triangles).",
                             lo=4)
    quality_threshold: float = _opt(C.DEFAULT_QUALITY_THRESHOLD, "pymeshlab quadric "
                                    "collapse: penalise collapses that create triangles "
                                    "of lower quality (0..1).", lo=0.0, hi=1.0)
    placement: str = _opt("auto", "Vertex placement of the quadric collapse: 'optimal', "
                          "'endpoint' (keeps corners of relief-covered blocks), or 'auto' "
                          "(both; keep the closer coarse mesh).",
                          choices=("auto", "optimal", "endpoint"))
    preserve_boundary: bool = _opt(False, "Keep every boundary vertex of an open mesh "
                                   "(spends the triangle budget on the boundary: on "
                                   "mountain_terrain.obj the coarse mesh becomes a fan "
                                   "of its 636 boundary edges).")
    preserve_topology: bool = _opt(True, "Forbid collapses that change the topology "
                                   "(keeps a closed mesh closed and its genus).")
    pre_decimate_above: int = _opt(C.DEFAULT_PRE_DECIMATE_ABOVE, "Inputs with more faces "
                                   "are first reduced to pre_decimate_faces with "
                                   "fast-simplification (0 = never).", lo=0)
    pre_decimate_faces: int = _opt(C.DEFAULT_PRE_DECIMATE_FACES, "Face count of the "
                                   "pre-decimation.", lo=100)


@dataclass(frozen=True)
class ParameterizeSettings(_Validated):
    atlas_width: int = _opt(C.DEFAULT_ATLAS_SIZE, "Atlas width in texels (width x height "
                            f"at most {C.MAX_ATLAS_TEXELS:,}).", lo=16, hi=C.MAX_ATLAS_SIDE)
    atlas_height: int = _opt(C.DEFAULT_ATLAS_SIZE, "Atlas height in texels.", lo=16,
                             hi=C.MAX_ATLAS_SIDE)
    padding: int = _opt(C.DEFAULT_PADDING, "Texels between charts (xatlas padding); at "
                        "least 2 so bilinear lookups never reach another chart.", lo=2, hi=64)
    max_chart_cost: float = _opt(C.DEFAULT_MAX_CHART_COST, "xatlas: cost limit of chart "
                                 "growing (lower = more, flatter charts).", lo=0.0, lo_open=True)
    normal_deviation_weight: float = _opt(C.DEFAULT_NORMAL_DEVIATION_WEIGHT, "xatlas: "
                                          "weight of normal deviation in chart growing "
                                          "(higher = charts break at hard edges).", lo=0.0)

    def __post_init__(self):
        super().__post_init__()
        check_atlas_texels(self.atlas_width, self.atlas_height, "parameterize")


def check_atlas_texels(w: int, h: int, where: str) -> None:
    """The product half of the shared atlas limit (each side is a field's range)."""
    if w * h > C.MAX_ATLAS_TEXELS:
        raise ConfigError(f"{where}: atlas_width x atlas_height = {w}x{h} = {w * h:,} texels, more than the limit "
                          f"of {C.MAX_ATLAS_TEXELS:,}")


@dataclass(frozen=True)
class CageSettings(_Validated):
    max_ray_distance: float = _opt(C.DEFAULT_MAX_RAY_DISTANCE_REL, "Longest ray from the "
                                   "coarse surface, as a fraction of the bbox diagonal; "
                                   "misses fall back to the closest point.",
                                   lo=0.0, hi=1.0, lo_open=True)


@dataclass(frozen=True)
class PreserveSettings(_Validated):
    proxy_faces: int = _opt(C.DEFAULT_PRESERVE_PROXY_FACES, "Preserve route: triangle count "
                            "of the low-pass proxy whose xatlas charts are carried to the "
                            "full mesh (0 = simplify.target_faces).", lo=0)
    seams: str = _opt("corners", "Preserve route: how chart borders are kept. 'corners' "
                      "(seam vertices moved onto the proxy chart's outline in UV, its "
                      "corners locked, meshoptimizer collapses along the straight stretches: "
                      "coarse UVs stay inside their charts); 'locked' (every border vertex "
                      "kept: exact, but a chart's outline bounds the triangle count from "
                      "below); 'free' (meshoptimizer collapses along the seams unhindered: "
                      "coarse UV triangles may leave their chart by several texels).",
                      choices=("corners", "locked", "free"))
    padding: int = _opt(C.DEFAULT_PRESERVE_PADDING, "Preserve route: texels between the "
                        "proxy's charts (xatlas padding; replaces parameterize.padding): "
                        "meshoptimizer checks flips in 3D only, and coarse UV triangles "
                        "folded in UV leave their chart by up to 2.7 texels on the wrinkled "
                        "torus, so charts are kept farther apart than the cage route's.",
                        lo=2, hi=64)
    uv_weight: float = _opt(C.DEFAULT_PRESERVE_UV_WEIGHT, "Preserve route: meshoptimizer's "
                            "weight of the UV error (meters on the surface) against the "
                            "position error.", lo=0.0)
    auto_max_error: float = _opt(C.DEFAULT_AUTO_MAX_ERROR_TEXELS, "--method auto: the "
                                 "preserve route is taken when it reaches the target and "
                                 "both reconstruction errors (p95) are within this many "
                                 "texel sizes.", lo=0.0, lo_open=True)


@dataclass(frozen=True)
class AtlasSettings(_Validated):
    gutter: int = _opt(C.DEFAULT_GUTTER, "Texels (Chebyshev) around covered texels "
                       "filled by dilation.", lo=2, hi=64)
    compression: str = _opt(C.DEFAULT_COMPRESSION, "EXR compression (lossless, readable "
                            "by OpenEXR 3.1).", choices=("zip", "piz"))


@dataclass(frozen=True)
class DecomposeSettings(_Validated):
    threshold: float = _opt(C.DEFAULT_COACD_THRESHOLD, "CoACD concavity threshold "
                            "(lower = more, tighter pieces).", lo=0.0, hi=1.0, lo_open=True)
    max_pieces: int = _opt(-1, "CoACD max_convex_hull: merge down to this many pieces "
                           "(-1 = no limit).", lo=-1)
    preprocess_mode: str = _opt("auto", "CoACD manifold pre-processing (a voxel remesh): "
                                "'auto' = only when the coarse mesh is not closed.",
                                choices=("auto", "on", "off"))
    preprocess_resolution: int = _opt(C.DEFAULT_COACD_PREPROCESS_RESOLUTION,
                                      "CoACD pre-processing voxel resolution.", lo=10)
    resolution: int = _opt(C.DEFAULT_COACD_RESOLUTION, "CoACD sampling resolution of the "
                           "concavity metric.", lo=100)
    mcts_nodes: int = _opt(C.DEFAULT_COACD_MCTS_NODES, "CoACD tree search: children per "
                           "node.", lo=1)
    mcts_iterations: int = _opt(C.DEFAULT_COACD_MCTS_ITERATIONS, "CoACD tree search "
                                "iterations.", lo=1)
    mcts_max_depth: int = _opt(C.DEFAULT_COACD_MCTS_MAX_DEPTH, "CoACD tree search depth.",
                               lo=1)
    map_tolerance: float = _opt(C.DEFAULT_MAP_TOLERANCE_REL, "A coarse triangle maps to a "
                                "piece when it lies within this fraction of the coarse "
                                "bbox diagonal of the piece's hull.", lo=0.0, hi=0.5)


@dataclass(frozen=True)
class QualitySettings(_Validated):
    samples: int = _opt(C.DEFAULT_QUALITY_SAMPLES, "Surface samples per direction of the "
                        "reconstruction error.", lo=C.MIN_QUALITY_SAMPLES)


SECTIONS: dict[str, type] = {
    "load": LoadSettings,
    "simplify": SimplifySettings,
    "parameterize": ParameterizeSettings,
    "cage": CageSettings,
    "preserve": PreserveSettings,
    "atlas": AtlasSettings,
    "decompose": DecomposeSettings,
    "quality": QualitySettings,
}

#: "preserve" is an alias of "pp" (stored as "pp", the name 1.0 readers know).
METHODS = ("cage", "pp", "preserve", "auto")


@dataclass(frozen=True)
class BakeSettings(_Validated):
    """Everything ``hbake.bake`` needs besides the input and output paths."""

    method: str = _opt("cage", "Baking route: 'cage' (simplify, parameterize the coarse "
                       "mesh, cast rays to the full mesh), 'pp' or its alias 'preserve' "
                       "(parameterization-preserving simplification, Sec. 6.1: chart a "
                       "proxy, carry the charts to the full mesh, rasterize it, simplify "
                       "with chart borders locked), or 'auto' (both; keep the preserve "
                       "bundle when it reaches the target within preserve.auto_max_error, "
                       "else the cage one).", choices=METHODS)
    seed: int = _opt(C.DEFAULT_SEED, "Seed of CoACD and of the quality sampling.",
                     lo=0, hi=2**31 - 1)
    load: LoadSettings = field(default_factory=LoadSettings)
    simplify: SimplifySettings = field(default_factory=SimplifySettings)
    parameterize: ParameterizeSettings = field(default_factory=ParameterizeSettings)
    cage: CageSettings = field(default_factory=CageSettings)
    preserve: PreserveSettings = field(default_factory=PreserveSettings)
    atlas: AtlasSettings = field(default_factory=AtlasSettings)
    decompose: DecomposeSettings = field(default_factory=DecomposeSettings)
    quality: QualitySettings = field(default_factory=QualitySettings)

    def __post_init__(self):
        super().__post_init__()
        if self.method == "preserve":
            object.__setattr__(self, "method", "pp")

    # --- conversions -------------------------------------------------------------------
    def to_dict(self) -> dict:
        """Plain nested dict (JSON/TOML-serialisable), as recorded in the manifest."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict, source: str = "settings") -> "BakeSettings":
        """Build from a nested dict; unknown keys and wrong types raise ConfigError."""
        if not isinstance(data, dict):
            raise ConfigError(f"{source}: expected a table of settings")
        kwargs: dict[str, Any] = {}
        top = {f.name: f for f in _scalar_fields(cls)}
        for key, value in data.items():
            if key in SECTIONS:
                if not isinstance(value, dict):
                    raise ConfigError(f"{source}: [{key}] must be a table")
                kwargs[key] = _build_section(SECTIONS[key], value, f"{source}: [{key}]")
            elif key in top:
                kwargs[key] = _coerce(top[key], value, f"{source}: {key}")
            else:
                raise ConfigError(f"{source}: unknown setting '{key}' "
                                  f"(known: {', '.join(list(top) + list(SECTIONS))})")
        return cls(**kwargs)

    @classmethod
    def from_toml(cls, path: str | Path) -> "BakeSettings":
        """Read a TOML config file (``configs/*.toml``)."""
        path = Path(path)
        try:
            data = tomllib.loads(read_regular(path, MAX_CONFIG_BYTES).decode("utf-8"))
        except UnicodeDecodeError:
            raise ConfigError(f"{path}: not valid TOML: not UTF-8 text") from None
        except FileNotFoundError:
            raise ConfigError(f"{path}: config file not found") from None
        except OSError as exc:
            raise ConfigError(f"{path}: cannot read config file: {exc.strerror}") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{path}: not valid TOML: {exc}") from None
        return cls.from_dict(data, source=str(path))

    def with_overrides(self, overrides: dict[str, Any], source: str = "option") -> "BakeSettings":
        """Return a copy with dotted keys replaced, e.g. {"simplify.target_faces": 800}."""
        data = self.to_dict()
        for dotted, value in overrides.items():
            parts = dotted.split(".")
            if len(parts) == 1 and parts[0] in data and parts[0] not in SECTIONS:
                data[parts[0]] = value
            elif len(parts) == 2 and parts[0] in SECTIONS:
                if parts[1] not in data[parts[0]]:
                    raise ConfigError(f"{source}: unknown setting '{dotted}'")
                data[parts[0]][parts[1]] = value
            else:
                raise ConfigError(f"{source}: unknown setting '{dotted}'")
        return BakeSettings.from_dict(data, source=source)


def _scalar_fields(cls) -> list[dataclasses.Field]:
    return [f for f in dataclasses.fields(cls) if f.name not in SECTIONS]


_TYPES = {"int": int, "float": float, "bool": bool, "str": str}


def _coerce(f: dataclasses.Field, value: Any, where: str):
    want = _TYPES[f.type if isinstance(f.type, str) else f.type.__name__]
    # bool is an int subclass in Python: reject it where a number is wanted.
    if want is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if not isinstance(value, want) or (want is not bool and isinstance(value, bool)):
        raise ConfigError(f"{where}: expected {want.__name__}, got {value!r}")
    _check(f, value, where)
    return value


def _check(f: dataclasses.Field, value: Any, where: str) -> None:
    md = f.metadata
    if md.get("choices") and value not in md["choices"]:
        raise ConfigError(f"{where}: {value!r} is not one of {', '.join(md['choices'])}")
    if isinstance(value, float) and not math.isfinite(value):
        raise ConfigError(f"{where}: {value!r} is not finite")
    lo, hi = md.get("lo"), md.get("hi")
    if lo is not None and (value < lo or (md.get("lo_open") and value == lo)):
        raise ConfigError(f"{where}: {value!r} must be {'>' if md.get('lo_open') else '>='} {lo}")
    if hi is not None and value > hi:
        raise ConfigError(f"{where}: {value!r} must be <= {hi}")


def _build_section(cls, data: dict, where: str):
    known = {f.name: f for f in dataclasses.fields(cls)}
    kwargs = {}
    for key, value in data.items():
        if key not in known:
            raise ConfigError(f"{where}: unknown setting '{key}' (known: {', '.join(known)})")
        kwargs[key] = _coerce(known[key], value, f"{where} {key}")
    try:
        return cls(**kwargs)
    except ConfigError as exc:   # a check across fields (the atlas's texel count)
        raise ConfigError(f"{where}: {exc}") from None


def describe() -> list[tuple[str, Any, str]]:
    """(dotted key, default, doc) of every setting, in TOML order (for docs and --help)."""
    rows = [(f.name, f.default, f.metadata["doc"]) for f in _scalar_fields(BakeSettings)]
    for name, cls in SECTIONS.items():
        for f in dataclasses.fields(cls):
            rows.append((f"{name}.{f.name}", f.default, f.metadata["doc"]))
    return rows


def parse_value(text: str) -> Any:
    """Parse the VALUE of ``--set KEY=VALUE`` as a TOML value; bare words are strings."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text
