"""Options and helpers shared by the compute commands: ``--threads``, and progress that works with and without a
terminal.

Threads: torch's CPU kernels run on an OpenMP pool. On a machine whose cores are busy with another process, a pool
as large as the machine spins waiting for its slowest thread and collapses (BENCHMARKS.md: "Threads"); the search
and the node test work on small batches that gain little from a second thread. So the compute commands use
``--threads`` (default :data:`DEFAULT_THREADS`, or ``$TORCHHAND_THREADS``) torch threads, and ``torchhand`` sets
``OMP_WAIT_POLICY=PASSIVE`` (idle OpenMP threads sleep rather than spin) unless the environment says otherwise.
The thread count is part of what makes a run reproducible: a seed with ``--max-nodes`` gives byte-identical
solutions on the same device, dtype and thread count.
"""

from __future__ import annotations

import os
import sys
import time

from ..errors import InputValueError

DEFAULT_THREADS = 1
"""torch threads of a compute command when neither ``--threads`` nor ``$TORCHHAND_THREADS`` says otherwise."""


def add_threads_argument(p) -> None:
    p.add_argument("--threads", type=int, default=None, metavar="N",
                   help=f"torch CPU threads (default ${{TORCHHAND_THREADS}} or {DEFAULT_THREADS}: robust on a busy "
                        f"machine; results are reproducible for a given thread count)")


def apply_threads(value: int | None) -> int:
    """Set torch's intra-op thread count from ``--threads`` / ``$TORCHHAND_THREADS`` / the default; returns it."""
    import torch

    if value is None:
        env = os.environ.get("TORCHHAND_THREADS", "").strip()
        try:
            value = int(env) if env else DEFAULT_THREADS
        except ValueError:
            raise InputValueError(f"TORCHHAND_THREADS: expected a positive integer, got {env!r}") from None
    if value < 1:
        raise InputValueError(f"--threads: expected an integer >= 1, got {value}")
    torch.set_num_threads(value)
    return value


def apply_graph_setting() -> bool:
    """CUDA graph replay of the solvers' loops (``torchhand.kernels.graphs``) on unless ``$TORCHHAND_CUDA_GRAPHS``
    is ``0``; returns whether it is on."""
    from torchhand.kernels import graphs

    env = os.environ.get("TORCHHAND_CUDA_GRAPHS", "1").strip()
    if env not in ("0", "1"):
        raise InputValueError(f"TORCHHAND_CUDA_GRAPHS: expected 0 or 1, got {env!r}")
    graphs.set_enabled(env == "1")
    return env == "1"


class Progress:
    """Progress of a long command: a tqdm bar on a terminal, otherwise a plain line on stderr every ``every``
    seconds (and at each new stage). ``update(stage, text, fraction=None)``; ``close()``."""

    def __init__(self, name: str, *, disable: bool = False, every: float = 5.0, stream=None):
        self.name, self.every = name, every
        self.stream = stream or sys.stderr
        self.disable = disable
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.bar = None
        self.last, self.stage = -1e9, None
        self.t0 = time.perf_counter()
        if self.tty and not disable:
            from tqdm import tqdm
            self.bar = tqdm(total=1000, desc=name, file=self.stream, bar_format="{desc}: {percentage:3.0f}%|{bar}| "
                                                                               "{elapsed} [{postfix}]")

    def update(self, stage: str, text: str, fraction: float | None = None) -> None:
        if self.disable:
            return
        if self.bar is not None:
            if fraction is not None:
                self.bar.n = int(1000 * min(max(fraction, 0.0), 1.0))
            self.bar.set_postfix_str(f"{stage}: {text}" if text else stage, refresh=True)
            return
        now = time.perf_counter()
        if stage != self.stage or now - self.last >= self.every:
            self.stage, self.last = stage, now
            print(f"{self.name}: {now - self.t0:6.1f} s  {stage}" + (f": {text}" if text else ""), file=self.stream,
                  flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
