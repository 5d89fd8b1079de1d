"""A bundle that validates always runs: `hbake validate` refuses at least
everything the C++ loader (`hrt check`) refuses, and every bundle both accept survives
`hrt query B B`.

Differential: the golden bundles, every variant of tests/golden/corrupt and hostile
variants generated here, one per limit of the loader (docs/input-contract.md: file sizes,
format_version, the manifest rules beyond the JSON Schema, the EXR header walk, PLY
headers, piece faces, the coverage check), at and past each bound. For each bundle:

* `hrt check` exits 0 or 3 (never a signal);
* if it refuses (exit 3), hbake refuses too (exit 10-16), with the same class;
* if both accept, `hrt query B B --pose-a 0 0 0 0 0 0 1 --pose-b 0.0001 0 0 0 0 0 1`
  exits 0.

hbake's verdict is `hbake validate`'s (the CLI for the golden and committed corrupt
bundles; hbake.bundle.check_bundle in process for the generated ones, which is what the
CLI runs, to keep the test well under a minute). Needs the hrt binary: $HRT, else
.venv/bin/hrt (make runtime), else PATH; skipped when there is none.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hrt_locate import hrt_binary

from hbake import bundle as hb
from hbake.errors import VALIDATE_EXIT

HERE = Path(__file__).resolve().parents[1]
REPO = HERE.parent
GOLDEN = HERE / "golden"
sys.path.insert(0, str(HERE))
from bundledata import cube_data  # noqa: E402
from hbakecli import _hbake, _sphere_hull  # noqa: E402

CLASS_OF_EXIT = {v: k for k, v in VALIDATE_EXIT.items()}
QUERY_POSES = ["--pose-a", "0", "0", "0", "0", "0", "0", "1",
               "--pose-b", "0.0001", "0", "0", "0", "0", "0", "1"]


def _hrt() -> str:
    return hrt_binary("the differential test of hbake validate against hrt check needs it")


def _run_hrt(hrt: str, *args) -> subprocess.CompletedProcess:
    return subprocess.run([hrt, *map(str, args)], capture_output=True, text=True, timeout=120)


def _hrt_verdict(hrt: str, bundle: Path) -> str | None:
    """None when `hrt check` accepts, else the class it names."""
    r = _run_hrt(hrt, "check", bundle)
    assert r.returncode in (0, 3), (f"hrt check {bundle.name}: exit {r.returncode} (a crash?)\n"
                                    f"{(r.stdout + r.stderr)[-2000:]}")
    if r.returncode == 0:
        return None
    line = r.stderr.strip().splitlines()[-1]
    assert line.startswith("hrt: error: "), line
    return line[len("hrt: error: "):].split(":", 1)[0]


def _hbake_cli_verdict(bundle: Path) -> tuple[str | None, str]:
    r = subprocess.run(_hbake() + ["validate", str(bundle)], capture_output=True, text=True,
                       timeout=120)
    assert "Traceback" not in r.stdout + r.stderr, (r.stdout + r.stderr)[-3000:]
    if r.returncode == 0:
        return None, ""
    assert r.returncode in CLASS_OF_EXIT, (r.returncode, r.stdout, r.stderr)
    return CLASS_OF_EXIT[r.returncode], r.stdout.splitlines()[0]


def _hbake_verdict(bundle: Path) -> tuple[str | None, str]:
    _, problems = hb.check_bundle(bundle)
    return (problems[0].cls, str(problems[0])) if problems else (None, "")


def _agree(hrt: str, bundle: Path, cli: bool = False) -> tuple[str | None, str | None]:
    """Both verdicts, asserting the contract; returns (hrt class, hbake class)."""
    h = _hrt_verdict(hrt, bundle)
    p, msg = _hbake_cli_verdict(bundle) if cli else _hbake_verdict(bundle)
    if h is not None:
        assert p is not None, f"{bundle.name}: hrt check refuses it ({h}), hbake validate accepts it"
        assert p == h, f"{bundle.name}: hrt check says {h}, hbake validate {p} ({msg})"
    if h is None and p is None:
        r = _run_hrt(hrt, "query", bundle, bundle, *QUERY_POSES)
        assert r.returncode == 0, (f"hrt query {bundle.name}: exit {r.returncode}\n"
                                   f"{(r.stdout + r.stderr)[-2000:]}")
    return h, p


# --------------------------------------------------------------------------- golden bundles

def _committed() -> list[Path]:
    """The golden bundles, the 1.2 one (format-1.2/) and the committed corrupt variants."""
    return (sorted(GOLDEN.glob("*.hbundle")) + sorted((GOLDEN / "format-1.2").glob("*.hbundle"))
            + sorted((GOLDEN / "corrupt").glob("*.hbundle")))


def test_golden_and_committed_corrupt_bundles_agree(hrt):
    index = json.loads((GOLDEN / "corrupt" / "index.json").read_text())
    want = {v["bundle"]: v["class"] for v in index["variants"]}
    assert len(want) == len(list((GOLDEN / "corrupt").glob("*.hbundle")))
    assert (GOLDEN / "format-1.2" / "ridged_box_pp.hbundle").is_dir()
    for b in _committed():
        h, p = _agree(hrt, b, cli=True)
        assert (h, p) == ((want[b.name],) * 2 if b.name in want else (None, None)), b.name


# --------------------------------------------------------------------------- generated variants

def _manifest(b: Path) -> dict:
    return json.loads((b / "manifest.json").read_text("utf-8"))


def _rehash(b: Path, m: dict | None = None) -> dict:
    m = _manifest(b) if m is None else m
    for entry in m["files"].values():
        p = b / entry["path"]
        if p.is_file() and p.stat().st_size < (64 << 20):
            blob = p.read_bytes()
            entry["bytes"], entry["sha256"] = len(blob), hashlib.sha256(blob).hexdigest()
    (b / "manifest.json").write_bytes(hb.manifest_bytes(m))
    return m


def _edit_manifest(**paths):
    """A variant setting manifest fields: key 'a__b' is m['a']['b']."""
    def apply(b: Path) -> None:
        m = _manifest(b)
        for key, value in paths.items():
            *head, last = key.split("__")
            d = m
            for k in head:
                d = d[k]
            d[last] = value
        (b / "manifest.json").write_bytes(hb.manifest_bytes(m))
    return apply


def _raw_manifest(edit):
    """A variant editing manifest.json's text (for what json.dumps cannot write)."""
    def apply(b: Path) -> None:
        p = b / "manifest.json"
        p.write_text(edit(p.read_text("utf-8")), "utf-8")
    return apply


def _raw_field(text: str):
    """An unknown top-level field whose JSON text is ``text``."""
    return _raw_manifest(lambda t: t.replace("{\n", '{\n  "zz": ' + text + ",\n", 1))


def _pad_manifest(total: int):
    """manifest.json of exactly ``total`` bytes (an unknown top-level field of spaces)."""
    def apply(b: Path) -> None:
        m = _manifest(b)
        m["zz_pad"] = ""
        base = len(hb.manifest_bytes(m))
        m["zz_pad"] = " " * (total - base)
        blob = hb.manifest_bytes(m)
        assert len(blob) == total
        (b / "manifest.json").write_bytes(blob)
    return apply


def _nested(depth: int):
    """settings.x nested so that the deepest array is at level ``depth`` (top level 1)."""
    def apply(b: Path) -> None:
        m = _manifest(b)
        m["settings"]["x"] = json.loads("[" * (depth - 2) + "]" * (depth - 2))
        (b / "manifest.json").write_bytes(hb.manifest_bytes(m))
    return apply


def _sparse(key: str, size: int):
    """The file of ``key`` grown (sparse) to ``size`` bytes: refused before it is read."""
    def apply(b: Path) -> None:
        os.truncate(b / _manifest(b)["files"][key]["path"], size)
    return apply


def _rename_file(key: str, new: str):
    def apply(b: Path) -> None:
        m = _manifest(b)
        os.rename(b / m["files"][key]["path"], b / new)
        m["files"][key]["path"] = new
        (b / "manifest.json").write_bytes(hb.manifest_bytes(m))
    return apply


# EXR headers: parsed into attributes and written back, the line offsets moved with them.

def _exr_split(blob: bytes):
    attrs, pos = [], 8
    while blob[pos] != 0:
        e = blob.index(b"\0", pos)
        name, pos = blob[pos:e], e + 1
        e = blob.index(b"\0", pos)
        typ, pos = blob[pos:e], e + 1
        n = struct.unpack_from("<i", blob, pos)[0]
        attrs.append([name, typ, blob[pos + 4:pos + 4 + n]])
        pos += 4 + n
    return blob[:8], attrs, pos + 1


def _exr_join(head: bytes, attrs, blob: bytes, end: int, rows: int) -> bytes:
    out = bytearray(head)
    for name, typ, value in attrs:
        out += name + b"\0" + typ + b"\0" + struct.pack("<i", len(value)) + value
    out += b"\0"
    delta = len(out) - end
    comp = dict((a[0], a[2]) for a in attrs).get(b"compression", b"\x03")[0]
    chunks = -(-rows // {3: 16, 4: 32}.get(comp, 1))
    offsets = np.frombuffer(blob, "<u8", chunks, end).astype(np.int64) + delta
    return bytes(out) + offsets.astype("<u8").tobytes() + blob[end + 8 * chunks:]


def _exr_edit(edit, version: int | None = None):
    """A variant rewriting atlas.exr's header: ``edit(attrs)`` changes the list in place."""
    def apply(b: Path) -> None:
        p = b / "atlas.exr"
        blob = p.read_bytes()
        head, attrs, end = _exr_split(blob)
        edit(attrs)
        if version is not None:
            head = head[:4] + struct.pack("<i", version)
        p.write_bytes(_exr_join(head, attrs, blob, end, _manifest(b)["atlas"]["height"]))
        _rehash(b)
    return apply


def _attr(name: str, typ: str, value: bytes):
    return lambda attrs: attrs.append([name.encode(), typ.encode(), value])


def _set_attr(name: str, typ: str | None = None, value: bytes | None = None, drop: bool = False):
    def edit(attrs):
        for a in attrs:
            if a[0] == name.encode():
                if drop:
                    attrs.remove(a)
                    return
                a[1] = a[1] if typ is None else typ.encode()
                a[2] = a[2] if value is None else value
                return
        raise KeyError(name)
    return edit


def _claim(name: str, typ: str, claimed: int):
    """An attribute whose size field claims ``claimed`` bytes (the header then ends)."""
    def apply(b: Path) -> None:
        p = b / "atlas.exr"
        blob = p.read_bytes()
        _, _, end = _exr_split(blob)
        extra = name.encode() + b"\0" + typ.encode() + b"\0" + struct.pack("<i", claimed) + b"abc"
        p.write_bytes(blob[:end - 1] + extra + blob[end - 1:])
        _rehash(b)
    return apply


def _chlist(n: int) -> bytes:
    names = ["A", "B", "G", "R"] + [f"X{k:03d}" for k in range(n - 4)]
    return b"".join(c.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for c in sorted(names)) + b"\0"


def _many_attrs(count: int):
    return lambda attrs: attrs.extend([f"x{k:04d}".encode(), b"int", struct.pack("<i", k)]
                                      for k in range(count - len(attrs)))


def _box(x0, y0, x1, y1) -> bytes:
    return struct.pack("<4i", x0, y0, x1, y1)


# Atlas texels: coverage against the UVs.

def _atlas_edit(edit):
    def apply(b: Path) -> None:
        m = _manifest(b)
        p = b / "atlas.exr"
        atlas = hb.read_atlas_exr(p)
        edit(atlas, b)
        hb.write_atlas_exr(p, atlas, compression=m["files"]["atlas"]["compression"])
        _rehash(b)
    return apply


def _inside_centre(b: Path) -> tuple[int, int]:
    """A texel whose centre is well inside coarse triangle 0's UV triangle."""
    _, _, uv = hb.read_coarse_ply(b / "coarse.ply")
    m = _manifest(b)
    w, h = m["atlas"]["width"], m["atlas"]["height"]
    c = uv[0].astype(np.float64).mean(axis=0)
    return int(c[0] * w), int((1 - c[1]) * h)


def _clear_inside(atlas, b):
    i, j = _inside_centre(b)
    atlas[j, i, 3] = 0.0


def _cover_outside(atlas, b):
    # the cube's charts leave 2-texel margins: texel (0, 0) is in no UV triangle, but
    # within the gutter (filled), so only the coverage check can see it
    assert atlas[0, 0, 3] == 0
    atlas[0, 0, 3] = 1.0


def _far_texel(value: float):
    # a covered texel's position at `value` m along x (the coordinate limit is 1e4 m)
    def edit(atlas, b):
        i, j = _inside_centre(b)
        atlas[j, i, 0] = value
    return edit


# Coordinates (the input contract's 1e4 m).

def _far_coarse_vertex(b: Path) -> None:
    v, f, uv = hb.read_coarse_ply(b / "coarse.ply")
    v = np.array(v, dtype=np.float64)
    v[0, 2] = 2e4
    hb.write_coarse_ply(b / "coarse.ply", v, f, uv)
    _rehash(b)


def _far_piece_vertex(b: Path) -> None:
    v, vid, f, fid, maps = hb.read_pieces_ply(b / "pieces.ply")
    v = np.array(v, dtype=np.float64)
    v[0, 1] = -2e4
    pv = [v[vid == k] for k in range(len(maps))]
    first = [int(np.flatnonzero(vid == k)[0]) for k in range(len(maps))]
    pf = [np.asarray(f)[np.asarray(fid) == k] - first[k] for k in range(len(maps))]
    hb.write_pieces_ply(b / "pieces.ply", pv, pf, maps)
    _rehash(b)


# Pieces.

def _pieces(extra_face: bool):
    def apply(b: Path) -> None:
        hv, hf = _sphere_hull(1024, np.random.default_rng(2), (0.05, 0.05, 0.05), 0.04)
        assert len(hv) == 1024 and len(hf) == hb.MAX_PIECE_FACES
        if extra_face:
            hf = np.concatenate([hf, hf[:1]])
        hb.write_pieces_ply(b / "pieces.ply", [hv], [hf], [np.array([0], np.uint32)])
        m = _manifest(b)
        m["pieces"]["count"] = 1
        _rehash(b, m)
    return apply


def _pieces_count(piece: int, add: int):
    """pieces.ply with the coarse_face_count of ``piece`` changed by ``add`` (rehashed)."""
    def apply(b: Path) -> None:
        p = b / "pieces.ply"
        blob = bytearray(p.read_bytes())
        v, _, f, _, maps = hb.read_pieces_ply(p)
        at = blob.index(b"end_header\n") + len(b"end_header\n") + 16 * len(v) + 17 * len(f) + 4 * piece
        blob[at:at + 4] = struct.pack("<I", len(maps[piece]) + add)
        p.write_bytes(bytes(blob))
        _rehash(b)
    return apply


def _ply_header(key: str, old: bytes, new: bytes):
    def apply(b: Path) -> None:
        p = b / _manifest(b)["files"][key]["path"]
        blob = p.read_bytes()
        assert old in blob[:400]
        p.write_bytes(blob.replace(old, new, 1))
        _rehash(b)
    return apply


def _long_comment(total_header: int):
    """coarse.ply with its comment line grown so that the header is ``total_header`` bytes."""
    def apply(b: Path) -> None:
        p = b / "coarse.ply"
        blob = p.read_bytes()
        end = blob.index(b"end_header\n") + len(b"end_header\n")
        start = blob.index(b"comment ")
        stop = blob.index(b"\n", start)
        pad = total_header - end
        p.write_bytes(blob[:stop] + b"x" * pad + blob[stop:])
        _rehash(b)
    return apply


MIB = 1 << 20
GIB = 1 << 30
SHA = "0" * 64

#: (name, apply, expected class of both readers or None when both must accept)
VARIANTS = [
    # manifest.json size: the loader's 1 MiB
    ("manifest_1mib", _pad_manifest(MIB), None),
    ("manifest_over_1mib", _pad_manifest(MIB + 1), "io"),
    # format_version: at most 32 characters
    ("version_32_chars", _edit_manifest(format_version="1." + "0" * 29 + "3"), None),
    ("version_33_chars", _edit_manifest(format_version="1." + "0" * 31), "version"),
    # nesting
    ("nesting_64", _nested(64), None),
    ("nesting_65", _nested(65), "schema"),
    # the loader's manifest rules beyond the JSON Schema
    ("sha256_trailing_newline", _edit_manifest(source__sha256=SHA + "\n"), "schema"),
    ("file_sha256_trailing_newline", _edit_manifest(files__pieces__sha256=SHA + "\n"), "schema"),
    ("source_name_dot", _edit_manifest(source__name="."), "schema"),
    ("source_name_dotdot", _edit_manifest(source__name="a..b"), "schema"),
    ("file_path_dotdot", _rename_file("coarse_mesh", "coarse..ply"), "schema"),
    ("file_path_nul", _edit_manifest(files__pieces__path="pieces\0.ply"), "schema"),
    ("file_path_twice", _edit_manifest(files__atlas__path="coarse.ply"), "schema"),
    ("file_path_manifest", _edit_manifest(files__atlas__path="manifest.json"), "schema"),
    ("atlas_side_65537", _edit_manifest(atlas__width=65537, files__atlas__width=65537), "schema"),
    ("gutter_over", _edit_manifest(atlas__gutter=(1 << 20) + 1), "schema"),
    ("seed_2_63", _edit_manifest(seeds__coacd=1 << 63), "schema"),
    ("seed_int64_max", _edit_manifest(seeds__coacd=(1 << 63) - 1), None),
    ("seed_1e19_float", _edit_manifest(seeds__quality=1e19), "schema"),
    ("count_1e30", _edit_manifest(source__vertices=10 ** 30), "schema"),
    ("lone_surrogate", _raw_field('"\\ud800"'), "schema"),
    ("paired_surrogate", _raw_field('"\\ud83d\\ude00"'), None),
    ("huge_integer_literal", _raw_field("1" + "0" * 400), "schema"),
    ("big_integer_literal", _raw_field("1" + "0" * 300), None),
    # file sizes, checked before reading (sparse files)
    ("coarse_over_1gib", _sparse("coarse_mesh", GIB + 1), "io"),
    ("pieces_over_1gib", _sparse("pieces", GIB + 1), "io"),
    ("atlas_over_512mib", _sparse("atlas", 512 * MIB + 1), "io"),
    # PLY headers
    ("ply_count_2_32", _ply_header("coarse_mesh", b"element vertex 8\n", b"element vertex 4294967296\n"), "mesh"),
    ("ply_header_4096", _long_comment(4096), None),
    ("ply_header_4097", _long_comment(4097), "mesh"),
    # the EXR header walk
    ("exr_string_claims_gigabytes", _claim("comments", "string", 1_670_000_000), "atlas"),
    ("exr_negative_size", _claim("comments", "string", -5), "atlas"),
    ("exr_name_31", _exr_edit(_attr("n" * 31, "int", b"\0\0\0\0")), None),
    ("exr_name_32", _exr_edit(_attr("n" * 32, "int", b"\0\0\0\0")), "atlas"),
    ("exr_type_32", _exr_edit(_attr("n", "t" * 32, b"\0\0\0\0")), "atlas"),
    ("exr_1024_attributes", _exr_edit(_many_attrs(1024)), None),
    ("exr_1025_attributes", _exr_edit(_many_attrs(1025)), "atlas"),
    ("exr_header_over_1mib", _exr_edit(_attr("comments", "string", b"c" * MIB)), "atlas"),
    ("exr_preview_inconsistent", _exr_edit(_attr("preview", "preview", struct.pack("<II", 100, 100))), "atlas"),
    ("exr_preview_overflow", _exr_edit(_attr("preview", "preview", struct.pack("<II", 1 << 31, 1 << 31))),
     "atlas"),
    ("exr_preview_ok", _exr_edit(_attr("preview", "preview", struct.pack("<II", 2, 1) + b"\0" * 8)), None),
    ("exr_stringvector_entry", _exr_edit(_attr("sv", "stringvector", struct.pack("<i", 1000) + b"ab")), "atlas"),
    ("exr_stringvector_ok", _exr_edit(_attr("sv", "stringvector", struct.pack("<i", 2) + b"ab")), None),
    ("exr_65_channels", _exr_edit(_set_attr("channels", value=_chlist(65))), "atlas"),
    ("exr_chlist_truncated", _exr_edit(_set_attr("channels", value=_chlist(4)[:30])), "atlas"),
    ("exr_no_data_window", _exr_edit(_set_attr("dataWindow", drop=True)), "atlas"),
    ("exr_data_window_box2f", _exr_edit(_set_attr("dataWindow", typ="box2f")), "atlas"),
    ("exr_data_window_20_bytes", _exr_edit(_set_attr("dataWindow", value=_box(0, 0, 47, 31) + b"\0" * 4)),
     "atlas"),
    ("exr_data_window_offset", _exr_edit(_set_attr("dataWindow", value=_box(1, 0, 48, 31))), "atlas"),
    ("exr_data_window_huge", _exr_edit(_set_attr("dataWindow", value=_box(0, 0, 16383, 16383))), "atlas"),
    ("exr_data_window_not_manifest", _exr_edit(_set_attr("dataWindow", value=_box(0, 0, 31, 31))), "atlas"),
    ("exr_tiled_flag", _exr_edit(lambda a: None, version=2 | 0x200), "atlas"),
    ("exr_unknown_flag", _exr_edit(lambda a: None, version=2 | 0x4000), "atlas"),
    ("exr_version_3", _exr_edit(lambda a: None, version=3), "atlas"),
    ("exr_truncated_header", lambda b: ((b / "atlas.exr").write_bytes((b / "atlas.exr").read_bytes()[:200]),
                                        _rehash(b)), "atlas"),
    # coverage against the UVs (the loader's check)
    ("coverage_missing_inside", _atlas_edit(_clear_inside), "atlas"),
    ("coverage_outside_every_triangle", _atlas_edit(_cover_outside), "atlas"),
    # coordinates within 1e4 m of the origin (a texel at the limit must still run: the
    # frame rasterizes its height, 1e4 m from the patch)
    ("atlas_texel_at_9999_m", _atlas_edit(_far_texel(9999.0)), None),
    ("atlas_texel_at_10001_m", _atlas_edit(_far_texel(10001.0)), "atlas"),
    ("coarse_vertex_at_2e4_m", _far_coarse_vertex, "mesh"),
    ("piece_vertex_at_2e4_m", _far_piece_vertex, "pieces"),
    # pieces.ply's map (format 1.3: per-piece counts, then the rows) and its layout,
    # which follows the version (1.0-1.2: one list per piece)
    ("pieces_map_counts_disagree", _pieces_count(0, 1), "pieces"),
    ("pieces_map_rows_2_32", _ply_header("pieces", b"element piece_coarse_face 20\n",
                                         b"element piece_coarse_face 4294967296\n"), "pieces"),
    ("pieces_1_3_layout_as_1_2", _edit_manifest(format_version="1.2"), "pieces"),
    ("pieces_1_3_layout_as_1_02", _edit_manifest(format_version="1.02"), "pieces"),
    ("pieces_1_3_layout_as_1_30", _edit_manifest(format_version="1.30"), None),
    # piece faces
    ("piece_2044_faces", _pieces(False), None),
    ("piece_2045_faces", _pieces(True), "pieces"),
]


@pytest.fixture(scope="module")
def cube_bundle(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("agree") / "cube.hbundle"
    hb.write_bundle(out, cube_data())
    return out


@pytest.mark.parametrize("name, apply, want", VARIANTS, ids=[v[0] for v in VARIANTS])
def test_generated_variant_agrees(hrt, cube_bundle, tmp_path, name, apply, want):
    b = tmp_path / f"{name}.hbundle"
    shutil.copytree(cube_bundle, b)
    apply(b)
    h, p = _agree(hrt, b)
    assert (h, p) == (want, want), f"{name}: hrt {h}, hbake {p} (variant meant {want})"
