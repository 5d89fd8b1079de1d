"""The convex pieces' invariants: index ranges, piece sizes, convexity within the
tolerance of the spec."""
from __future__ import annotations

import numpy as np

#: Most vertices of one convex piece (docs/input-contract.md, shared with the runtime):
#: the convexity test is vertices x faces per piece, so this bounds it at 1024 plane
#: tests per face, linear in the file.
MAX_PIECE_VERTICES = 1024
#: Most faces of one convex piece (the C++ loader's kMaxPieceFaces): a closed convex
#: triangulated polyhedron of V vertices has 2 V - 4 faces.
MAX_PIECE_FACES = 2 * MAX_PIECE_VERTICES - 4
#: Plane tests per batch of the convexity check: the (faces x vertices) distance
#: matrices of a batch take 8 bytes per test, twice (8 MiB x 2 at 2^20).
_CONVEX_BATCH = 1 << 20
#: Faces per chunk of pieces checked together (bounded temporaries, ~100 bytes a face).
_CHUNK_FACES = 1 << 17


def _piece_invariants(v, f, vp, fp, vstart, fstart, check, tol):
    """Closedness, zero-area faces, orientation and convexity of the pieces selected by
    ``check`` (a mask over pieces), with time and memory linear in the file.

    Each piece gets the first failing check of: closed and consistently wound; no
    zero-area face; positive volume; convex within ``tol``. Returns the lists
    (open, degenerate, inward, nonconvex) for the messages of check_pieces."""
    p = len(vstart) - 1
    fsel = np.flatnonzero(check[fp])
    open_mask = np.zeros(p, dtype=bool)
    ff = f[fsel].astype(np.int64)
    fpp = fp[fsel].astype(np.int64)
    # closed: every directed edge once and its reverse once (global indices are fine: a
    # face only uses vertices of its own piece, checked before)
    n = np.uint64(len(v))
    src = ff.ravel().astype(np.uint64)
    dst = ff[:, [1, 2, 0]].ravel().astype(np.uint64)
    key = np.sort(src * n + dst)
    dup = np.flatnonzero(key[1:] == key[:-1])
    open_mask[vp[(key[dup] // n).astype(np.int64)]] = True
    rkey = dst * n + src
    pos = np.minimum(np.searchsorted(key, rkey), max(len(key) - 1, 0))
    missing = key[pos] != rkey if len(key) else np.zeros(0, dtype=bool)
    open_mask[vp[src[missing].astype(np.int64)]] = True
    open_ = [int(k) for k in np.flatnonzero(open_mask & check)]
    # zero-area faces, then orientation, for the closed pieces
    alive = check & ~open_mask
    keep = alive[fpp]
    ff, fpp, fsel = ff[keep], fpp[keep], fsel[keep]
    a, b, c = v[ff[:, 0]], v[ff[:, 1]], v[ff[:, 2]]
    ln = np.linalg.norm(np.cross(b - a, c - a), axis=1)
    zero = ln == 0
    degen = []
    if zero.any():
        first = {}
        for gi, k in zip(fsel[zero].tolist(), fpp[zero].tolist()):
            first.setdefault(k, gi - int(fstart[k]))
        degen = sorted(first.items())
        alive[list(first)] = False
    nvp = np.diff(vstart).astype(np.float64)
    ctr = np.stack([np.bincount(vp, weights=v[:, i], minlength=p) for i in range(3)], axis=1)
    ctr /= np.maximum(nvp, 1)[:, None]
    cf = ctr[fpp]
    vol_f = np.einsum("ij,ij->i", a - cf, np.cross(b - cf, c - cf)) / 6.0
    vol = np.bincount(fpp, weights=vol_f, minlength=p)
    inward_mask = alive & (vol <= 0)
    inward = [(int(k), float(vol[k])) for k in np.flatnonzero(inward_mask)]
    alive &= ~inward_mask
    nonconvex = _convexity(v, f, vstart, fstart, np.flatnonzero(alive), tol)
    return open_, degen, inward, nonconvex


def _convexity(v, f, vstart, fstart, pieces, tol):
    """(piece, worst distance, local face, local vertex) of every piece with a vertex more
    than ``tol`` in front of one of its face planes.

    Every vertex of a piece is tested against every face plane of it. Pieces are batched
    by size (vertex and face counts rounded up to powers of two, padded with copies of
    their last vertex and face, which change no maximum), so many small pieces cost a
    few numpy calls rather than one each, and every batch holds at most _CONVEX_BATCH
    tests. Positions are taken relative to the piece's first vertex, as exact as
    n . (x - a) per pair."""
    out = []
    if len(pieces) == 0:
        return out
    nv = (vstart[pieces + 1] - vstart[pieces]).astype(np.int64)
    nf = (fstart[pieces + 1] - fstart[pieces]).astype(np.int64)
    pv_pad = 1 << np.ceil(np.log2(nv)).astype(np.int64)
    pf_pad = 1 << np.ceil(np.log2(nf)).astype(np.int64)
    buckets: dict[tuple[int, int], list[int]] = {}
    for i, (a, b) in enumerate(zip(pv_pad.tolist(), pf_pad.tolist())):
        buckets.setdefault((a, b), []).append(i)
    for (vpad, fpad), members in sorted(buckets.items()):
        members = np.asarray(members)
        if vpad * fpad > _CONVEX_BATCH:      # one big piece: face chunks, no padding
            for i in members.tolist():
                res = _convex_one(v, f, int(pieces[i]), vstart, fstart, tol)
                if res is not None:
                    out.append(res)
            continue
        per = max(1, _CONVEX_BATCH // (vpad * fpad))
        for s in range(0, len(members), per):
            idx = members[s:s + per]
            ks = pieces[idx]
            vi = vstart[ks][:, None] + np.minimum(np.arange(vpad)[None, :], nv[idx][:, None] - 1)
            fi = fstart[ks][:, None] + np.minimum(np.arange(fpad)[None, :], nf[idx][:, None] - 1)
            ref = v[vstart[ks]][:, None, :]
            pts = v[vi] - ref                                    # (B, vpad, 3)
            tri = v[f[fi].astype(np.int64)] - ref[:, None, :, :]  # (B, fpad, 3, 3)
            nrm = np.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])
            nrm /= np.linalg.norm(nrm, axis=2, keepdims=True)
            off = np.einsum("bfk,bfk->bf", nrm, tri[:, :, 0])
            dist = np.matmul(nrm, pts.transpose(0, 2, 1))        # (B, fpad, vpad)
            dist -= off[:, :, None]
            flat = dist.reshape(len(idx), -1)
            arg = flat.argmax(axis=1)
            worst = flat[np.arange(len(idx)), arg]
            for j in np.flatnonzero(worst > tol).tolist():
                fj, vj = divmod(int(arg[j]), vpad)
                out.append((int(ks[j]), float(worst[j]), fj, vj))
    out.sort()
    return out


# Rows per product in _rows_max: 32 x 4 x 1024 multiply-adds stay below OpenBLAS's
# threshold for starting threads (65,536 x 4).
_GEMM_ROWS = 32


def _rows_max(plane: np.ndarray, pts4: np.ndarray) -> np.ndarray:
    """``(plane @ pts4).max(axis=1)`` as a stack of products of _GEMM_ROWS rows each, one
    numpy call. OpenBLAS runs each small product on one thread, where one big product
    started its threads for a few microseconds of work: 200 pieces of 1024 vertices took
    2.4-7 s on a loaded 2-core box instead of 0.15 s (the float32 pass's error bound
    covers any order of its 4-term sums, so the verdict does not depend on this)."""
    n = len(plane)
    m = -(-n // _GEMM_ROWS) * _GEMM_ROWS
    if m != n:
        plane = np.concatenate([plane, np.repeat(plane[-1:], m - n, axis=0)])
    stacked = np.matmul(plane.reshape(-1, _GEMM_ROWS, plane.shape[1]), pts4)
    return stacked.max(axis=2).reshape(-1)[:n]


def _convex_one(v, f, k, vstart, fstart, tol):
    pv = v[vstart[k]:vstart[k + 1]]
    ref = 0.5 * (pv.min(axis=0) + pv.max(axis=0))
    pts = pv - ref
    pf = f[fstart[k]:fstart[k + 1]].astype(np.int64)
    # A float32 pass (one matrix product with the plane offset folded in, half the
    # memory traffic of float64) finds the faces that may fail; only those are redone
    # in float64, so the verdict is the float64 one. Its error is below
    # bound = 16 u ext (u = 2^-24: rounding of the inputs and of a 4-term dot product,
    # positions taken from the piece's centre); when 2 bound < tol, a face that fails
    # in float64 has a float32 maximum above tol - bound, and a face whose vertices lie
    # on or behind its plane does not.
    ext = float(np.abs(pts).max())
    bound = 16 * ext * 2.0 ** -24
    exact32 = 2 * bound < tol
    margin = bound
    pts4 = np.hstack([pts, np.ones((len(pts), 1))]).astype(np.float32).T.copy()
    chunk = max(1, _CONVEX_BATCH // len(pv))
    best = (-np.inf, 0, 0)
    for s in range(0, len(pf), chunk):
        tri = v[pf[s:s + chunk]] - ref
        nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        off = np.einsum("fk,fk->f", nrm, tri[:, 0])
        if exact32:
            plane = np.hstack([nrm, -off[:, None]]).astype(np.float32)
            rough = _rows_max(plane, pts4)
            sel = np.flatnonzero(rough > tol - margin)
            if len(sel) == 0:
                continue
        else:
            sel = np.arange(len(nrm))
        dist = nrm[sel] @ pts.T
        dist -= off[sel][:, None]
        a = int(np.argmax(dist))
        fi, vi = divmod(a, len(pv))
        if dist[fi, vi] > best[0]:
            best = (float(dist[fi, vi]), s + int(sel[fi]), vi)
    return (k, best[0], best[1], best[2]) if best[0] > tol else None
