"""`hbake plot` draws against session time: a real-time trace has ~10 kHz of frames out of
contact and ~1 kHz in it, so against the frame number the contact would be squeezed into
the plot's last few per cent; and Fig. 9's title rates the frames in contact."""
from __future__ import annotations

import numpy as np

from hbake.viz import plot as P

COLUMNS = ["t", "frame", "probe_x", "probe_y", "probe_z", "probe_qx", "probe_qy", "probe_qz", "probe_qw",
           "contact_fx", "contact_fy", "contact_fz", "contact_tx", "contact_ty", "contact_tz", "patches",
           "collision_us", "clustering_us", "force_us", "total_us"]


def _trace(tmp_path):
    # 0.95 s free at 10 kHz (frames of 2 us), then 1 s in contact at 1 kHz (frames of 500 us).
    t = np.concatenate([np.arange(9500) * 1e-4, 0.95 + np.arange(1000) * 1e-3])
    n = len(t)
    contact = t >= 0.95
    rows = np.zeros((n, len(COLUMNS)))
    col = {c: i for i, c in enumerate(COLUMNS)}
    rows[:, col["t"]] = t
    rows[:, col["frame"]] = np.arange(1, n + 1)
    rows[:, col["probe_qw"]] = 1.0
    rows[:, col["contact_fz"]] = np.where(contact, 1.0, 0.0)
    rows[:, col["patches"]] = contact
    rows[:, col["total_us"]] = np.where(contact, 500.0, 2.0)
    path = tmp_path / "rt.csv"
    with open(path, "w") as f:
        f.write(",".join(COLUMNS) + "\n")
        for r in rows:
            f.write(",".join(repr(float(v)) for v in r) + "\n")
    return P.Trace(path), t


def test_figures_are_drawn_against_session_time(tmp_path, monkeypatch):
    tr, t = _trace(tmp_path)
    figs = []
    monkeypatch.setattr(P, "_save", lambda fig, path: figs.append(fig) or path)
    P.fig7(tr, tmp_path / "a.png")
    P.fig8(tr, tmp_path / "b.png")
    P.fig9(tr, tmp_path / "c.png")
    for fig in figs:
        bottom = fig.axes[-1]
        assert bottom.get_xlabel() == "session time (s)"
        x = bottom.get_lines()[0].get_xdata()
        assert np.array_equal(x, t)
    # The contact (the last second) spans half the time axis, not the last 10 % of the rows.
    assert (t >= 0.95).sum() / len(t) < 0.1
    # Fig. 9 rates the frames in contact: 500 us, 2 kHz (not 2 us, 500 kHz).
    title = figs[2]._suptitle.get_text()
    assert "0.50 ms a frame in contact" in title and "(2000 Hz of compute)" in title, title
