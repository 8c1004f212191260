"""Replaying a kernel's fixed-shape loop as one captured CUDA graph, and the check that a loop can be captured.

An iterative kernel on a GPU is bound by launches when its batch is small: every elementwise operation of every
iteration is a kernel launch of a few microseconds, and the arithmetic takes less. A loop body that runs a fixed
number of iterations on fixed shapes, without a host synchronisation (no ``.item()``, ``bool(tensor)``,
``nonzero``, boolean-mask indexing, copies to the host), can be captured once as a CUDA graph and replayed with
one launch.

:func:`replayed` does that on CUDA tensors and simply calls the function elsewhere:

- ``fn(*tensors)`` must be a pure function of its tensor arguments (every other value it reads is constant for
  the same ``key``, and the tensors it closes over keep their storage: the graph of the first call reads them
  by address, so the first ``fn`` is kept with its graph) returning a tensor or a tuple of tensors.
- The first call for a key (the key is extended by the arguments' shapes, dtypes and devices) runs ``fn``
  eagerly twice on a side stream (the warm-up CUDA graphs need), captures it, replays it on the same inputs and
  compares the replay with the eager result bit for bit. A capture that raises or differs marks the key eager for
  good (counted in :data:`STATS`); the answer returned is always the eager one or a replay proved equal to it.
- Later calls copy their inputs into the graph's static buffers, replay, and return clones of the outputs.
- At most :data:`MAX_GRAPHS` graphs are kept (least recently used dropped); they share one memory pool.
- :func:`set_enabled` (False) turns replay off (every call eager); the command line does so for
  ``TORCHHAND_CUDA_GRAPHS=0`` in the environment.

:func:`no_host_sync` is the check, on any device: inside it, an operation that needs the host to wait for the
device (on a GPU) raises :class:`HostSyncError`. Tests run the captured loops under it on the CPU, so a loop that
could not be captured is found without a GPU.
"""

from __future__ import annotations

from typing import Callable

import torch
from torch.utils._python_dispatch import TorchDispatchMode

__all__ = ["replayed", "padded", "bucket", "no_host_sync", "host_sync", "HostSyncError", "STATS", "MAX_GRAPHS", "clear",
           "in_replayed", "gpu_paths", "fixed_loops", "set_enabled"]

MAX_GRAPHS = 64
# regions (calls of a function given to replayed(), on any device), captures, replays, eager calls on CUDA (a key
# whose capture failed or differed), failed captures
STATS: dict = {"regions": 0, "captures": 0, "replays": 0, "eager": 0, "failed": 0}
_GRAPHS: dict = {}          # insertion order = least recently used first
_EAGER = object()           # a key whose capture failed: run eagerly
_POOL = None
_ENABLED = True            # set_enabled()
_FORCE = False             # gpu_paths()
_CHECK = False             # gpu_paths(check_syncs=True)
_DEPTH = 0                  # > 0 while a function given to replayed() runs (for op counting)

# operations that read a device value on the host (or whose output shape depends on values)
_SYNC_OPS = ("aten._local_scalar_dense", "aten.nonzero", "aten.masked_select", "aten._unique", "aten.unique",
             "aten.repeat_interleave.Tensor", "aten.item", "aten.equal", "aten.is_nonzero", "aten._assert_async")


class HostSyncError(RuntimeError):
    """An operation inside :func:`no_host_sync` needs a host synchronisation (on a GPU)."""


def host_sync(func, args=(), kwargs=None) -> str | None:
    """Why the operator call ``func(*args, **kwargs)`` (as a dispatch mode sees it) synchronises with the host on a
    GPU, or None: reading a value, a data-dependent output shape, boolean-mask indexing, a copy between devices."""
    name = str(func)
    if name.startswith(_SYNC_OPS):
        return f"{name} synchronises with the host"
    if name.startswith("aten.index.Tensor") and any(i is not None and i.dtype == torch.bool for i in args[1]):
        return "boolean-mask indexing synchronises with the host"
    if name.startswith("aten._to_copy") and "device" in (kwargs or {}) and args and \
            torch.device(kwargs["device"]) != args[0].device:
        return f"a copy from {args[0].device} to {kwargs['device']} synchronises with the host"
    return None


class no_host_sync(TorchDispatchMode):
    """Context manager: raise :class:`HostSyncError` at the first operation that would synchronise with the host
    on a GPU (:func:`host_sync`)."""

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        why = host_sync(func, args, kwargs)
        if why is not None:
            raise HostSyncError(why)
        return func(*args, **(kwargs or {}))


class gpu_paths:
    """Context manager: within it, :func:`fixed_loops` is true on every device, so the CPU runs the loops as a GPU
    does (for the tests, and to count what a GPU would launch); check_syncs: every function given to
    :func:`replayed` off CUDA runs under :class:`no_host_sync` (a loop that could not be captured raises)."""

    def __init__(self, check_syncs: bool = False):
        self.check_syncs = check_syncs

    def __enter__(self):
        global _FORCE, _CHECK
        self.old = _FORCE, _CHECK
        _FORCE, _CHECK = True, self.check_syncs
        return self

    def __exit__(self, *exc):
        global _FORCE, _CHECK
        _FORCE, _CHECK = self.old
        return False


def set_enabled(flag: bool) -> bool:
    """Turn graph replay on or off (off: every call eager, as on the CPU); returns the previous setting. The
    command line reads ``TORCHHAND_CUDA_GRAPHS=0`` from the environment."""
    global _ENABLED
    old, _ENABLED = _ENABLED, bool(flag)
    return old


def fixed_loops(device: torch.device) -> bool:
    """Whether loops on ``device`` run their whole iteration count without a host check (to be captured): on
    CUDA, or within :func:`gpu_paths`."""
    return device.type == "cuda" or _FORCE


def in_replayed() -> bool:
    """Whether a function given to :func:`replayed` is running (its operations would be one graph replay)."""
    return _DEPTH > 0


def clear() -> None:
    """Drop every captured graph and every key marked eager."""
    _GRAPHS.clear()


def _signature(tensors) -> tuple:
    return tuple((tuple(t.shape), t.dtype, t.device) for t in tensors)


def _as_tuple(out) -> tuple:
    return out if isinstance(out, tuple) else (out,)


def _call(fn: Callable, tensors):
    global _DEPTH
    STATS["regions"] += 1
    _DEPTH += 1
    try:
        return fn(*tensors)
    finally:
        _DEPTH -= 1


def bucket(n: int) -> int:
    """The batch size a batch of n rows is padded to on CUDA: the next power of two up to 4096, then the next
    multiple of 4096 (a few shapes, so a few captures, for the many batch sizes of a search)."""
    return max(8, 1 << (n - 1).bit_length()) if n <= 4096 else -(-n // 4096) * 4096


def padded(fn: Callable, rows: int, tensors):
    """``fn`` on ``tensors`` whose leading ``rows`` rows are batch rows, padded with copies of the first row to
    :func:`bucket` (rows), its outputs (batch-first) cut back to ``rows``. Batch rows must not interact in ``fn``:
    a row's answer is then the same, padded or not."""
    n = bucket(rows)
    if n == rows:
        return fn(*tensors)
    pick = torch.cat([torch.arange(rows, device=tensors[0].device),
                      torch.zeros(n - rows, dtype=torch.long, device=tensors[0].device)])
    out = fn(*(t.index_select(0, pick) for t in tensors))
    return tuple(o[:rows] for o in out) if isinstance(out, tuple) else out[:rows]


def replayed(key: tuple, fn: Callable, *tensors: torch.Tensor, rows: int | None = None):
    """``fn(*tensors)``; on CUDA replayed from a graph captured once per ``key`` and argument shapes (see the
    module docstring). rows: every argument and output is batch-first with this many rows, independent of one
    another: on CUDA the batch is padded to :func:`bucket` (rows) (fewer shapes, fewer captures). Returns what
    ``fn`` returns (tensors the caller owns)."""
    if not tensors or tensors[0].device.type != "cuda" or not _ENABLED:
        if _CHECK:
            with no_host_sync():
                return _call(fn, tensors)
        return _call(fn, tensors)
    if rows is not None and bucket(rows) != rows:
        return padded(lambda *t: replayed(key, fn, *t), rows, tensors)
    full = (key, _signature(tensors))
    entry = _GRAPHS.get(full)
    if entry is _EAGER:
        STATS["eager"] += 1
        return _call(fn, tensors)
    if entry is None:
        out, entry = _capture(fn, tensors)
        _GRAPHS[full] = entry
        while len(_GRAPHS) > MAX_GRAPHS:
            del _GRAPHS[next(iter(_GRAPHS))]
        return out
    _GRAPHS[full] = _GRAPHS.pop(full)                      # now the most recently used
    graph, static_in, static_out, single, _ = entry
    for buf, x in zip(static_in, tensors):
        buf.copy_(x)
    graph.replay()
    STATS["replays"] += 1
    outs = tuple(o.clone() for o in static_out)
    return outs[0] if single else outs


def _capture(fn: Callable, tensors):
    """(the eager answer, the cache entry): a verified graph, or _EAGER."""
    global _POOL
    stream = torch.cuda.Stream()
    stream.wait_stream(torch.cuda.current_stream())
    with torch.cuda.stream(stream):
        static_in = tuple(t.clone() for t in tensors)
        for _ in range(2):
            eager = _call(fn, static_in)
    torch.cuda.current_stream().wait_stream(stream)
    single = not isinstance(eager, tuple)
    eager = tuple(e.clone() for e in _as_tuple(eager))
    try:
        if _POOL is None:
            _POOL = torch.cuda.graph_pool_handle()
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph, pool=_POOL):
            static_out = _as_tuple(_call(fn, static_in))
        graph.replay()
        same = len(static_out) == len(eager) and all(
            a.shape == b.shape and torch.equal(a, b) for a, b in zip(static_out, eager))
    except RuntimeError:
        torch.cuda.synchronize()
        same = False
    STATS["captures" if same else "failed"] += 1
    out = eager[0] if single else eager
    # the entry keeps fn alive: tensors it closes over (constants the graph reads by address) must not be freed
    return out, ((graph, static_in, static_out, single, fn) if same else _EAGER)
