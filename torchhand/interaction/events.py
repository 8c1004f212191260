"""Contact events from force tracks (Kry & Pai 2006, §3.3; design note Stage 3 and ambiguity 6).

An event of sensor s is the first frame k where ``|f_s| > f_on`` after at least ``gap`` seconds (``n_gap`` frames)
with ``|f_s| <= f_on``. The paper gives no thresholds; here:

* force noise ``sigma`` (newtons per component) is estimated robustly from first differences of every force
  component: ``sigma = 1.4826 MAD(diff f) / sqrt(2)`` (a loaded force changes little between frames);
* ``f_on = max(force_threshold, 3 sqrt(3) sigma)`` (3 sigma of the norm's noise scale; default threshold 0.05 N);
* the contact frame is then moved back from the crossing while the previous frame's ``|f_s|`` exceeds the noise
  floor ``f_floor = max(3 sigma, 1e-9 N)`` (at most ``n_gap`` frames), so that the contact time ``t_c`` is the first
  loaded frame rather than the threshold crossing (the estimator's pre-contact window must be unloaded);
* events of sensors on one finger within ``gap`` of each other are merged into the earliest (``merge``);
* an event's contact ends at the first later frame where ``|f_s| <= f_floor``.

Conventions: frames at ``fps`` Hz; forces on the hand, newtons.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputValueError, ShapeError

__all__ = ["ContactEvents", "detect_contact_events", "force_noise"]


@dataclass(frozen=True)
class ContactEvents:
    """Contact events, E of them, in time order.

    frame:     first loaded frame of each event, (E,), int
    time:      frame / fps, (E,), seconds
    sensor:    the sensor that made contact (the earliest of a merged group), (E,), int
    sensors:   every sensor merged into the event, tuple of E tuples of int
    end_frame: first frame after the event's contact ends (or T), (E,), int
    threshold: f_on, newtons; floor: f_floor, newtons; noise: estimated force noise per component, newtons
    max_force: the largest |f_s| in the capture, newtons
    """

    frame: np.ndarray
    time: np.ndarray
    sensor: np.ndarray
    sensors: tuple
    end_frame: np.ndarray
    threshold: float
    floor: float
    noise: float
    max_force: float

    @property
    def count(self) -> int:
        return int(self.frame.shape[0])


def force_noise(force: np.ndarray) -> float:
    """Robust per-component noise of force tracks, newtons: 1.4826 MAD of first differences / sqrt(2).

    force: (T, S, 3), newtons
    """
    d = np.diff(force, axis=0).reshape(-1)
    if d.size == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(2.0))


def detect_contact_events(force: np.ndarray, fps: float, *, force_threshold: float = 0.05, gap: float = 0.05,
                          finger: np.ndarray | None = None, merge: bool = True) -> ContactEvents:
    """Contact events of every sensor (see the module docstring).

    force:           force on the hand per sensor, (T, S, 3), newtons
    fps:             frame rate, Hz
    force_threshold: lower bound of f_on, newtons
    gap:             quiet time required before an event (and the merge window), seconds
    finger:          finger index of each sensor's link, (S,), int, -1 for the palm (None: no merging)
    merge:           merge events of sensors on one finger within ``gap``
    returns: :class:`ContactEvents`
    """
    force = np.asarray(force, dtype=np.float64)
    if force.ndim != 3 or force.shape[2] != 3:
        raise ShapeError(f"force: expected shape (T, S, 3), got {force.shape}")
    if not force_threshold > 0:
        raise InputValueError(f"force_threshold: expected > 0 newtons, got {force_threshold}")
    if not gap > 0:
        raise InputValueError(f"gap: expected > 0 seconds, got {gap}")
    T, S, _ = force.shape
    sigma = force_noise(force)
    f_on = max(float(force_threshold), 3.0 * np.sqrt(3.0) * sigma)
    f_floor = max(3.0 * sigma, 1e-9)
    mag = np.linalg.norm(force, axis=2)  # (T, S)
    n_gap = max(1, int(round(gap * fps)))
    above = mag > f_on
    # count of frames above f_on in [k - n_gap, k), per sensor
    csum = np.concatenate([np.zeros((1, S)), np.cumsum(above, axis=0)], axis=0)
    k = np.arange(T)
    quiet = np.zeros((T, S), dtype=bool)
    ok = k >= n_gap
    quiet[ok] = (csum[k[ok]] - csum[k[ok] - n_gap]) == 0
    onset_k, onset_s = np.nonzero(above & quiet)
    frames, sensors = [], []
    for kk, s in zip(onset_k.tolist(), onset_s.tolist()):
        lo = max(kk - n_gap, 0)
        while kk > lo and mag[kk - 1, s] > f_floor:
            kk -= 1
        frames.append(kk)
        sensors.append(s)
    order = sorted(range(len(frames)), key=lambda i: (frames[i], sensors[i]))
    groups: list[list[int]] = []  # [frame, sensor, sensors...]
    for i in order:
        kk, s = frames[i], sensors[i]
        if merge and finger is not None and int(finger[s]) >= 0:
            for g in groups:
                if kk - g[0] <= n_gap and int(finger[g[1]]) == int(finger[s]) and s not in g[2:]:
                    g.append(s)
                    break
            else:
                groups.append([kk, s, s])
        else:
            groups.append([kk, s, s])
    ends = []
    for g in groups:
        kk, s = g[0], g[1]
        below = np.nonzero(mag[kk + 1:, s] <= f_floor)[0]
        ends.append(kk + 1 + int(below[0]) if below.size else T)
    frame = np.array([g[0] for g in groups], dtype=np.int64)
    return ContactEvents(frame=frame, time=frame / float(fps), sensor=np.array([g[1] for g in groups], dtype=np.int64),
                         sensors=tuple(tuple(g[2:]) for g in groups), end_frame=np.array(ends, dtype=np.int64),
                         threshold=f_on, floor=f_floor, noise=sigma, max_force=float(mag.max()) if mag.size else 0.0)
