"""Timing helpers shared by the benchmark scripts: median and spread of repeated runs, GPU-synchronised."""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from typing import Callable

import torch


def sync(device: str | torch.device) -> None:
    device = torch.device(device)
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def time_fn(fn: Callable[[], object], device: str = "cpu", repeats: int = 7, warmup: int = 2,
            min_time: float = 0.0) -> dict:
    """Run ``fn`` ``warmup`` times, then ``repeats`` timed runs (each repeated until ``min_time`` seconds).

    Returns median, min, max and interquartile range of the per-call seconds.
    """
    for _ in range(warmup):
        fn()
    sync(device)
    samples = []
    for _ in range(repeats):
        n = 0
        t0 = time.perf_counter()
        while True:
            fn()
            n += 1
            sync(device)
            dt = time.perf_counter() - t0
            if dt >= min_time:
                break
        samples.append(dt / n)
    q = statistics.quantiles(samples, n=4) if len(samples) >= 2 else [samples[0]] * 3
    return {"median_s": statistics.median(samples), "min_s": min(samples), "max_s": max(samples),
            "iqr_s": q[2] - q[0], "repeats": repeats}


def machine() -> dict:
    info = {"python": platform.python_version(), "torch": torch.__version__, "cpu": platform.processor()
            or platform.machine(), "cores": os.cpu_count(), "threads": torch.get_num_threads()}
    if torch.cuda.is_available():
        info["gpu"] = torch.cuda.get_device_name(0)
    return info


def print_table(rows: list[dict], columns: list[str]) -> None:
    widths = [max(len(c), *(len(_fmt(r.get(c))) for r in rows)) for c in columns]
    print("  ".join(c.ljust(w) for c, w in zip(columns, widths)))
    print("  ".join("-" * w for w in widths))
    for r in rows:
        print("  ".join(_fmt(r.get(c)).ljust(w) for c, w in zip(columns, widths)))


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return "" if v is None else str(v)


def write_json(path: str, payload: dict) -> None:
    tmp = f"{path}.tmp"
    with open(tmp, "w") as fh:
        json.dump(payload, fh, indent=2)
    os.replace(tmp, path)


def alternate(script: str, args: list[str], checkouts: list[str], alternations: int, env: dict | None = None) -> dict:
    """A/B runs of ``script`` (its hidden ``--one`` mode, printing one JSON line last) for each checkout in turn,
    ``alternations`` times, each in its own process with the checkout first on ``PYTHONPATH`` (and ``env`` added).
    Returns {checkout (absolute): [the JSON of each alternation]}, in the order given."""
    import subprocess
    import sys

    trees = [os.path.abspath(c) for c in checkouts]
    runs = {t: [] for t in trees}
    for _ in range(alternations):
        for t in trees:
            out = subprocess.run([sys.executable, os.path.abspath(script), *args, "--one"],
                                 env=dict(os.environ, **(env or {}), PYTHONPATH=t), capture_output=True, text=True,
                                 check=True, cwd=t)
            runs[t].append(json.loads(out.stdout.strip().splitlines()[-1]))
    return runs


def print_ratios(runs: dict, key: str, unit: str, label: str = "", extra=lambda r: "") -> None:
    """Per checkout of :func:`alternate`'s ``runs``: ``key`` of every alternation, their median and its ratio to the
    first checkout's, and ``extra(last run)``."""
    trees = list(runs)
    base = statistics.median(r[key] for r in runs[trees[0]])
    for t in trees:
        per = [r[key] for r in runs[t]]
        m = statistics.median(per)
        print(f"{label}{t}: {' / '.join(f'{x:.2f}' for x in per)} {unit}; median {m:.2f}, ratio {m / base:.2f}"
              f"{extra(runs[t][-1])}")

