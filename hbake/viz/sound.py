"""The texture as sound: the high-frequency part of a session's contact force, as audio.

``hbake plot TRACE.csv --audio`` writes ``<trace stem>.wav``; the viewer (hbake/viz/viewer.py)
plays the same signal in the page. The signal is what a hand would feel as vibration:

1. the texture contact force on the probe (trace columns ``contact_fx, contact_fy,
   contact_fz``; docs/trace-format.md), or with ``source="device"`` the force written to
   the device (``fx, fy, fz``), sampled at the frames' session times ``t``;
2. resampled onto the audio clock (linear interpolation between frames: a real-time
   trace's frames are not evenly spaced);
3. high-passed at ``cutoff`` (scipy's 4th-order Butterworth, run forwards and backwards:
   no phase shift, and its odd-extension padding keeps a steady push or a ramp at the ends
   from becoming a click): the slow push of the contact is felt as force, not heard;
4. projected on the direction along which it varies most (its principal axis), so one
   channel keeps the vibration whatever the contact's orientation;
5. faded in and out over 10 ms, then normalized to 0.9 of full scale (a silent trace
   stays silent).

Time is not stretched: a ridge met every 10 ms plays at 100 Hz, its frequency in the hand.
A frame rate below twice the highest vibration aliases it; the texture's vibration can
only be as fine as the simulation's rate (``hrt run``'s summary prints it).
"""
from __future__ import annotations

import os
import tempfile
import wave
from pathlib import Path

import numpy as np

from hbake.errors import InputInvalidError, OutputUnwritableError

#: Audio sample rate (Hz) of the WAV files.
DEFAULT_RATE = 44100
#: High-pass cutoff (Hz): what varies slower than this is force, not sound.
DEFAULT_CUTOFF = 20.0
FADE_S = 0.01
FULL_SCALE = 0.9
SOURCES = {"contact": ("contact_fx", "contact_fy", "contact_fz"), "device": ("fx", "fy", "fz")}


def vibration(t: np.ndarray, force: np.ndarray, rate: int = DEFAULT_RATE,
              cutoff: float = DEFAULT_CUTOFF) -> np.ndarray:
    """The vibration signal (float64, in [-FULL_SCALE, FULL_SCALE]) of ``force`` (F, 3)
    sampled at times ``t`` (F,), on a clock of ``rate`` Hz from t[0] to t[-1]."""
    t = np.asarray(t, float)
    force = np.asarray(force, float).reshape(len(t), -1)
    if len(t) < 2 or not np.all(np.diff(t) > 0):
        raise ValueError("the times must increase, with at least two frames")
    if not (rate >= 1000 and cutoff > 0):
        raise ValueError("rate must be >= 1000 Hz and cutoff > 0")
    n = int(np.floor((t[-1] - t[0]) * rate)) + 1
    ts = t[0] + np.arange(n) / rate
    from scipy.signal import butter, sosfiltfilt

    x = np.stack([np.interp(ts, t, force[:, k]) for k in range(force.shape[1])], axis=1)
    x = x - x.mean(axis=0)
    sos = butter(4, min(cutoff, 0.45 * rate), btype="highpass", fs=rate, output="sos")
    pad = min(n - 1, 3 * int(rate / cutoff))
    x = sosfiltfilt(sos, x, axis=0, padtype="odd", padlen=pad) if n > 12 else np.zeros_like(x)
    # The principal axis of the vibration (its largest-variance direction).
    cov = x.T @ x
    if not np.any(cov):
        return np.zeros(n)
    w, vecs = np.linalg.eigh(cov)
    s = x @ vecs[:, -1]
    fade = min(int(FADE_S * rate), n // 2)
    if fade > 0:
        ramp = np.linspace(0.0, 1.0, fade, endpoint=False)
        s[:fade] *= ramp
        s[n - fade:] *= ramp[::-1]
    peak = np.max(np.abs(s))
    # Below 1e-12 of the force's own scale it is rounding, not vibration.
    if not peak > 1e-12 * max(1.0, float(np.max(np.abs(force)))):
        return np.zeros(n)
    return s * (FULL_SCALE / peak)


def trace_vibration(trace, rate: int = DEFAULT_RATE, cutoff: float = DEFAULT_CUTOFF,
                    source: str = "contact") -> np.ndarray:
    """vibration() of a trace (hbake.viz.plot.Trace): its ``source`` force against ``t``."""
    if source not in SOURCES:
        raise ValueError(f"source must be one of {', '.join(SOURCES)}")
    t = trace["t"]
    f = np.column_stack([trace[c] for c in SOURCES[source]])
    if len(t) < 2 or not np.all(np.diff(t) > 0):
        raise InputInvalidError(f"{trace.path}: the sound needs at least two frames with increasing t")
    return vibration(t, f, rate, cutoff)


def wav_bytes(signal: np.ndarray, rate: int = DEFAULT_RATE) -> bytes:
    """A mono 16-bit PCM WAV file of ``signal`` (values in [-1, 1])."""
    import io
    pcm = np.round(np.clip(signal, -1.0, 1.0) * 32767).astype("<i2")
    buf = io.BytesIO()
    with wave.open(buf, "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(int(rate))
        w.writeframes(pcm.tobytes())
    return buf.getvalue()


def write_wav(path: Path, signal: np.ndarray, rate: int = DEFAULT_RATE) -> Path:
    """Writes ``signal`` to ``path`` atomically (a temporary sibling renamed into place)."""
    path = Path(path)
    data = wav_bytes(signal, rate)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    except OSError as exc:
        raise OutputUnwritableError(f"{path}: cannot write the sound: {exc.strerror}") from None
    return path


def read_wav(path: Path) -> tuple[np.ndarray, int]:
    """The samples (float64 in [-1, 1]) and rate of a mono 16-bit WAV written here."""
    with wave.open(str(path), "rb") as w:
        if w.getnchannels() != 1 or w.getsampwidth() != 2:
            raise InputInvalidError(f"{path}: expected a mono 16-bit WAV")
        rate = w.getframerate()
        pcm = np.frombuffer(w.readframes(w.getnframes()), dtype="<i2")
    return pcm.astype(np.float64) / 32767, rate
