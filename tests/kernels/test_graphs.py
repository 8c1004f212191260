"""The graph replay helper: CPU behaviour, padding, the host-sync check, and (with a GPU) capture and replay."""

from __future__ import annotations

import pytest
import torch

from torchhand.kernels import graphs
from torchhand.kernels.graphs import HostSyncError, bucket, no_host_sync, padded, replayed


def _rowwise(a: torch.Tensor, b: torch.Tensor):
    """A batch-row-independent loop: 30 steps of a small batched product and elementwise updates."""
    for _ in range(30):
        a = torch.tanh(torch.bmm(b, a.unsqueeze(-1)).squeeze(-1)) + 0.1 * a
    return a, a.norm(dim=-1)


def _inputs(n: int, device: str = "cpu", seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(n, 6, generator=g, dtype=torch.float64).to(device),
            torch.randn(n, 6, 6, generator=g, dtype=torch.float64).to(device) / 3)


@pytest.mark.parametrize("op", [
    lambda x: x.sum().item(),
    lambda x: bool((x > 0).any()),
    lambda x: x.nonzero(),
    lambda x: x[x > 0],
    lambda x: torch.masked_select(x, x > 0),
])
def test_the_sync_check_refuses_what_waits_for_the_device(op):
    x = torch.randn(5, 3)
    with pytest.raises(HostSyncError):
        with no_host_sync():
            op(x)


def test_the_sync_check_lets_pure_tensor_work_through():
    a, b = _inputs(7)
    with no_host_sync():
        got = _rowwise(a, b)
    want = _rowwise(a, b)
    assert all(torch.equal(x, y) for x, y in zip(got, want))


def test_off_cuda_replayed_calls_the_function_and_counts_the_region():
    a, b = _inputs(7)
    before = graphs.STATS["regions"]
    assert not graphs.in_replayed()
    seen = []

    def fn(a, b):
        seen.append(graphs.in_replayed())
        return _rowwise(a, b)

    got = replayed(("test", 1), fn, a, b, rows=7)
    assert seen == [True] and not graphs.in_replayed()
    assert graphs.STATS["regions"] == before + 1
    assert all(torch.equal(x, y) for x, y in zip(got, _rowwise(a, b)))   # off CUDA: never padded


def test_gpu_paths_with_sync_checks_raise_inside_replayed_functions():
    x = torch.randn(4, 3)
    with graphs.gpu_paths(check_syncs=True):
        assert graphs.fixed_loops(torch.device("cpu"))
        with pytest.raises(HostSyncError):
            replayed(("test", 2), lambda x: x[x > 0].sum(), x)
    assert not graphs.fixed_loops(torch.device("cpu"))
    assert replayed(("test", 2), lambda x: x[x > 0].sum(), x) == x[x > 0].sum()


def test_the_command_line_reads_the_graph_setting(monkeypatch):
    from torchhand.cli._common import apply_graph_setting
    from torchhand.errors import InputValueError

    try:
        monkeypatch.setenv("TORCHHAND_CUDA_GRAPHS", "0")
        assert apply_graph_setting() is False and graphs.set_enabled(False) is False
        monkeypatch.setenv("TORCHHAND_CUDA_GRAPHS", "yes")
        with pytest.raises(InputValueError, match="TORCHHAND_CUDA_GRAPHS"):
            apply_graph_setting()
        monkeypatch.delenv("TORCHHAND_CUDA_GRAPHS")
        assert apply_graph_setting() is True and graphs.set_enabled(True) is True
    finally:
        graphs.set_enabled(True)


def test_buckets_are_few_and_cover_every_size():
    sizes = [bucket(n) for n in range(1, 20000)]
    assert all(s >= n for n, s in zip(range(1, 20000), sizes))
    assert len(set(sizes)) == len({8, 16, 32, 64, 128, 256, 512, 1024, 2048, 4096}) + 4
    assert bucket(256) == 256 and bucket(257) == 512 and bucket(4097) == 8192 and bucket(3) == 8


@pytest.mark.parametrize("n", [1, 5, 8, 100])
def test_padding_keeps_every_row_as_it_is_alone(n):
    a, b = _inputs(n, seed=n)
    got = padded(_rowwise, n, (a, b))
    assert got[0].shape == (n, 6) and got[1].shape == (n,)
    for i in range(n):   # each row against itself in a batch of two (never one, see kernels._rows)
        alone = _rowwise(a[[i, i]], b[[i, i]])
        assert torch.equal(got[0][i], alone[0][0]) and torch.equal(got[1][i], alone[1][0])


cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")


@cuda
def test_cuda_replay_equals_eager_and_is_reused():
    graphs.clear()
    a, b = _inputs(100, "cuda")
    want = _rowwise(*padded(lambda *t: t, 100, (a, b)))
    s0 = dict(graphs.STATS)
    first = replayed(("test cuda",), _rowwise, a, b, rows=100)
    assert graphs.STATS["captures"] == s0.get("captures", 0) + 1
    for seed in (1, 2):
        a2, b2 = _inputs(100, "cuda", seed)
        got = replayed(("test cuda",), _rowwise, a2, b2, rows=100)
        ref = _rowwise(*padded(lambda *t: t, 100, (a2, b2)))
        assert torch.equal(got[0], ref[0][:100]) and torch.equal(got[1], ref[1][:100])
    assert graphs.STATS["replays"] >= s0.get("replays", 0) + 2
    assert torch.equal(first[0], want[0][:100])


@cuda
def test_cuda_a_function_that_syncs_runs_eagerly():
    graphs.clear()
    x = torch.randn(16, 3, device="cuda")
    f0 = graphs.STATS["failed"]
    out = replayed(("test sync",), lambda x: x * float(x.sum()), x)
    assert torch.equal(out, x * float(x.sum()))
    assert graphs.STATS["failed"] == f0 + 1
    assert torch.equal(replayed(("test sync",), lambda x: x * float(x.sum()), x), x * float(x.sum()))
