"""The result directory of ``torchhand splice`` (format in ``docs/splice.md``).

Files
    ``spliced.bvh``  the body clip with its finger joints (and, with ``--wrist hand``, its wrist) driven by the
                     re-timed hand; every other channel as in the body file
    ``warp.npz``     ``body_frame (n,)`` int, body frames 0..n-1; ``hand_time (n,)`` float64, the hand frame shown
                     at each body frame (fractional hand frames, 0-based); ``hand_seconds (n,)`` the same in
                     seconds of the hand clip; ``map1 (n,)`` pass 1's median hand frame per body frame;
                     ``path1 (L1, 2)`` and ``path2 (L2, 2)`` int, the DTW paths' cells (body frame, hand frame)
                     and (body frame, aligned frame), path2 empty (0, 2) when pass 2 did not run; ``cost1 (n, m)``
                     and ``cost2 (n, n)`` float32 (cost2 (0, 0) when pass 2 did not run)
    ``report.json``  inputs, rigs, units, rates, band widths, matching points, pass 2 used or why not, local
                     speed range, joints carried, timings

Nothing lost: the output place is checked before any work (:func:`prepare_out`): a directory that holds
something other than an earlier splice result is never written into; an earlier result is replaced only with
``overwrite``; every file is written atomically.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from .._atomic import atomic_bytes, atomic_json, writable_dir
from ..scene.bvh import write_bvh
from ..errors import InputValueError
from .splice import SpliceResult

__all__ = ["prepare_out", "write_splice", "RESULT_FILES"]

RESULT_FILES = ("spliced.bvh", "warp.npz", "report.json")


def prepare_out(out, *, overwrite: bool = False) -> Path:
    """Validate (and create) the output directory before any work; one-line InputValueError otherwise."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputValueError(f"--out {out}: exists and is not a directory")
    if out.is_dir() and any(out.iterdir()):
        if not (out / "report.json").is_file():
            raise InputValueError(f"--out {out}: exists, is not empty and is not a splice result; choose a new "
                                  "directory (nothing was written)")
        if not overwrite:
            raise InputValueError(f"--out {out}: holds an earlier splice result; pass --overwrite to replace it or "
                                  "choose another directory")
    return writable_dir(out)


def warp_arrays(result: SpliceResult) -> dict:
    """The arrays of ``warp.npz`` (module docstring)."""
    al = result.alignment
    n = al.hand_frame.shape[1]
    p1 = al.path1[0]
    p1 = p1[p1[:, 0] >= 0].numpy()
    used = bool(al.pass2_used[0])
    p2 = al.path2[0]
    p2 = p2[p2[:, 0] >= 0].numpy() if used else np.zeros((0, 2), dtype=np.int64)
    cost2 = al.cost2[0].numpy() if (used and al.cost2 is not None) else np.zeros((0, 0), dtype=np.float32)
    hand_fps = result.report["hand_fps"]
    return {
        "body_frame": np.arange(n, dtype=np.int64),
        "hand_time": al.hand_frame[0].numpy().astype(np.float64),
        "hand_seconds": (al.hand_frame[0].numpy() / hand_fps).astype(np.float64),
        "map1": al.map1[0].numpy().astype(np.float64),
        "path1": p1.astype(np.int64),
        "path2": p2.astype(np.int64),
        "cost1": al.cost1[0].numpy().astype(np.float32),
        "cost2": cost2.astype(np.float32),
    }


def write_splice(result: SpliceResult, out) -> Path:
    """Write ``spliced.bvh``, ``warp.npz`` and ``report.json`` into ``out`` (prepared by :func:`prepare_out`)."""
    out = Path(out)
    write_bvh(result.clip, out / "spliced.bvh")
    buf = io.BytesIO()
    np.savez_compressed(buf, **warp_arrays(result))
    atomic_bytes(out / "warp.npz", buf.getvalue())
    atomic_json(out / "report.json", result.report)
    return out
