"""The texture as sound (hbake/viz/sound.py, `hbake plot --audio`), through the real chain.

The 4 mm ball tip slides at 60 mm/s for 1 s over a grating of 0.8 mm wavelength (ridges at
23 degrees to the path: 0.869 mm along it) baked by `hbake bake` (tests/sessions.py,
``fine_strip``), in `hrt run --lockstep` at 1 kHz: 14.5 times the ridge frequency
speed x cos 23 / wavelength = 69.0 Hz. `hbake plot --audio` writes the trace's sound; the
WAV's spectral peak (Hann window, zero-padded 16 times: 0.06 Hz bins) is within 2 % of the
ridge frequency, and the WAV is mono 16-bit at 44.1 kHz, as long as the session, never
clipped.
"""
from __future__ import annotations

import math
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

import sessions as S

SPEED = 0.06
X0, X1, Y = 3e-3, 63e-3, 4e-3
PRESS = 0.2e-3
SETTLE = 0.3
RIDGE_HZ = SPEED * math.cos(math.radians(S.STRIP_ANGLE)) / S.FINE_L
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    return Path(os.environ.get("FULLSURFACE_CACHE") or tmp_path_factory.getbasetemp() / "fullsurface")


def test_the_wav_of_a_slide_peaks_at_the_ridge_frequency(root, tmp_path):
    from hbake.viz.sound import read_wav

    tip, strip = S.bake("tip", root), S.bake("fine_strip", root)
    z = S.STRIP_THICK + S.FINE_A + S.TIP_R - PRESS
    T = (X1 - X0) / SPEED
    times = [0.0, SETTLE, SETTLE + T]
    pos = [[X0, Y, z], [X0, Y, z], [X1, Y, z]]
    traj = S.write_trajectory(tmp_path / "slide.traj.csv", times, pos, [[0, 0, 0, 1]] * 3)
    trace = tmp_path / "slide.csv"
    S.run_scene(tmp_path, "slide", {
        "run": {"duration": times[-1], "lockstep": True},
        "object": [{"name": "tip", "bundle": tip.bundle, "position": pos[0]},
                   {"name": "strip", "bundle": strip.bundle}],
        "device": {"trajectory": traj},
        "loop": {"soft_start": 0.1},
        "trace": {"path": trace},
    })
    res = subprocess.run([str(REPO / ".venv" / "bin" / "hbake"), "plot", str(trace), "--audio", "--figure", "fig7",
                          "-o", str(tmp_path / "out")], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    wav = tmp_path / "out" / "slide.wav"
    assert str(wav) in res.stdout.split()
    x, rate = read_wav(wav)
    assert rate == 44100
    assert abs(len(x) / rate - times[-1]) < 2e-3
    assert np.max(np.abs(x)) <= 0.9 + 1e-4            # normalized, never clipped
    # The slide only (the settle and the soft start left out).
    s = x[int((SETTLE + 0.1) * rate):]
    w = np.hanning(len(s))
    n = 16 * len(s)
    F = np.abs(np.fft.rfft(s * w, n))
    fr = np.fft.rfftfreq(n, 1.0 / rate)
    band = fr >= 5.0
    peak = fr[band][np.argmax(F[band])]
    print(f"slide at {SPEED * 1e3:.0f} mm/s over {S.FINE_L * 1e3} mm: ridge {RIDGE_HZ:.2f} Hz, WAV peak "
          f"{peak:.2f} Hz ({peak / RIDGE_HZ - 1:+.2%})")
    assert abs(peak / RIDGE_HZ - 1) <= 0.02
    # Not silence: the slide's sound is loud where the ridges are.
    assert np.sqrt(np.mean(s ** 2)) > 0.1


def test_vibration_of_a_known_signal():
    """A 30 N push plus a 0.01 N, 150 Hz ripple sampled at uneven frame times: the sound is
    the ripple (the push removed), at 150 Hz, normalized to 0.9."""
    from hbake.viz.sound import vibration

    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, 2000))
    f = np.zeros((len(t), 3))
    f[:, 2] = 30.0 * np.minimum(t / 0.2, 1.0) + 0.01 * np.sin(2 * np.pi * 150 * t)
    s = vibration(t, f, 44100, 20.0)
    assert abs(np.max(np.abs(s)) - 0.9) < 1e-12
    mid = s[int(0.3 * 44100):-int(0.1 * 44100)]
    F = np.abs(np.fft.rfft(mid * np.hanning(len(mid)), 16 * len(mid)))
    fr = np.fft.rfftfreq(16 * len(mid), 1 / 44100)
    assert abs(fr[np.argmax(F)] - 150.0) < 1.0
    assert np.all(vibration(t, np.ones((len(t), 3))) == 0)       # a constant force is silent


def test_the_sound_never_overwrites_its_trace(tmp_path):
    """A trace named like the WAV it would make (x.wav) in the output folder: exit 6 with
    one line, the trace unchanged and nothing written; elsewhere (-o) the WAV is made."""
    import shutil

    src = REPO / "tests" / "data" / "viewer" / "press.trace.csv"
    trace = tmp_path / "x.wav"
    shutil.copy(src, trace)
    exe = str(REPO / ".venv" / "bin" / "hbake")
    res = subprocess.run([exe, "plot", str(trace), "--audio"], capture_output=True, text=True, timeout=300)
    assert res.returncode == 6 and res.stderr.count("\n") == 1 and "x.wav" in res.stderr, res.stderr
    assert trace.read_bytes() == src.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.wav"]
    res = subprocess.run([exe, "plot", str(trace), "--audio", "--figure", "fig7", "-o", str(tmp_path / "o")],
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    from hbake.viz.sound import read_wav
    x, rate = read_wav(tmp_path / "o" / "x.wav")
    assert rate == 44100 and len(x) > 0.29 * rate
