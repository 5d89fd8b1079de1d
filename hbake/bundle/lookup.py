"""UV <-> texel and the bilinear atlas lookup of the spec ("UV to texel")."""
from __future__ import annotations

import numpy as np

# --------------------------------------------------------------------------- UV <-> texel

def texel_coords(uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """Continuous texel coordinates (x, y) of UVs: x = u W - 0.5, y = (1 - v) H - 0.5.

    Texel centres are at integer (x, y); row 0 (y = 0) is the first stored scanline,
    the top of the image, since v points up."""
    uv = np.asarray(uv, dtype=np.float64)
    x = uv[..., 0] * width - 0.5
    y = (1.0 - uv[..., 1]) * height - 0.5
    return np.stack([x, y], axis=-1)


def atlas_lookup(atlas: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup of all channels at UVs, by the spec's convention.

    ``atlas`` is (H, W, C) with row 0 the top; ``uv`` is (K, 2) (or (2,)).
    Returns (K, C) float64 (or (C,)). The four texels are clamped to the image."""
    atlas = np.asarray(atlas)
    if atlas.ndim != 3:
        raise ValueError(f"atlas must be (H, W, C), got shape {atlas.shape}")
    h, w = atlas.shape[:2]
    uv = np.asarray(uv, dtype=np.float64)
    single = uv.ndim == 1
    uv = uv.reshape(-1, 2)
    xy = texel_coords(uv, w, h)
    x0f = np.floor(xy[:, 0])
    y0f = np.floor(xy[:, 1])
    fx = (xy[:, 0] - x0f)[:, None]
    fy = (xy[:, 1] - y0f)[:, None]
    x0 = x0f.astype(np.int64)
    y0 = y0f.astype(np.int64)
    i0 = np.clip(x0, 0, w - 1)
    i1 = np.clip(x0 + 1, 0, w - 1)
    j0 = np.clip(y0, 0, h - 1)
    j1 = np.clip(y0 + 1, 0, h - 1)
    a = atlas.astype(np.float64, copy=False)
    out = ((1 - fx) * (1 - fy) * a[j0, i0] + fx * (1 - fy) * a[j0, i1]
           + (1 - fx) * fy * a[j1, i0] + fx * fy * a[j1, i1])
    return out[0] if single else out
