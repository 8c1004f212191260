"""Shared fixtures: reference-data location, dtypes, deterministic generators. TF32 is off in tests."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch

torch.backends.cuda.matmul.allow_tf32 = False
torch.backends.cudnn.allow_tf32 = False

REPO = Path(__file__).resolve().parents[1]


def qpth_available() -> bool:
    """Is the optional extra qpth (``torchhand[qpth]``, NumPy < 2) importable here?"""
    import importlib.util
    return importlib.util.find_spec("qpth") is not None


# The qpth adapter's tests: they run in the NumPy 1 environment that has qpth (scripts/test_numpy1.sh, in CI).
requires_qpth = pytest.mark.skipif(not qpth_available(), reason="the qpth adapter needs the optional extra "
                                   "torchhand[qpth] (NumPy < 2); its tests run in scripts/test_numpy1.sh")


def shared_data_dir() -> Path:
    """``$TORCHHAND_SHARED_DATA`` or ``<repo>/../shared/data``."""
    return Path(os.environ.get("TORCHHAND_SHARED_DATA", REPO.parent / "shared" / "data"))


def shared_path(*parts: str) -> Path:
    """A path under the shared reference data; skips the test with a reason when it is absent."""
    p = shared_data_dir().joinpath(*parts)
    if not p.exists():
        pytest.skip(f"reference data not found: {p} (set TORCHHAND_SHARED_DATA)")
    return p


@pytest.fixture
def shared_data() -> Path:
    d = shared_data_dir()
    if not d.exists():
        pytest.skip(f"reference data not found: {d} (set TORCHHAND_SHARED_DATA)")
    return d


DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.fixture(params=DEVICES)
def device(request) -> str:
    return request.param


@pytest.fixture(params=[torch.float32, torch.float64], ids=["f32", "f64"])
def dtype(request) -> torch.dtype:
    return request.param


@pytest.fixture
def gen() -> torch.Generator:
    return torch.Generator().manual_seed(1234)


@pytest.fixture(scope="session")
def bpy():
    """Blender as a Python module (the optional extra ``torchhand[blender]``), imported once (about 1 s); the test
    is skipped with the reason when it cannot be imported."""
    try:
        import bpy as blender
    except ImportError as err:
        pytest.skip(f"bpy (Blender as a Python module) cannot be imported ({err}); it needs NumPy < 2: "
                    "pip install -e '.[blender]' in an environment of its own (scripts/setup.sh makes .venv-numpy1; "
                    "scripts/test_numpy1.sh runs these tests there)")
    return blender


@pytest.fixture
def one_intra_op_thread():
    """One intra-op thread for the test (small problems: on shared CPUs more threads only add contention)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


# The test files that take longest, with their seconds in two processes on the suite's 2-core machine (pytest
# --durations, 2026-11-30). scripts/test.sh spreads whole files over processes in collection order
# (--no-loadscope-reorder): these go first, longest first, so that no long file starts last and leaves the other
# process idle (the default order, by number of tests, put the single-test files last). Other files keep their order.
LONG_FILES = {
    "tests/torchhand/test_numerics.py": 290, "tests/torchhand/test_batch_acceptance.py": 272,
    "tests/torchhand/test_synthesis.py": 225, "tests/torchhand/test_batch.py": 180,
    "tests/torchhand/test_multi_search.py": 225, "tests/torchhand/test_mount_fit.py": 55,
    "tests/torchhand/test_synthesis_output.py": 105, "tests/torchhand/test_check.py": 90,
    "tests/torchhand/test_liu_scenes.py": 76, "tests/torchhand/test_sdf.py": 67,
    "tests/torchhand/test_fill_pieces.py": 61, "tests/render/test_render_cli.py": 60,
    "tests/torchhand/test_mount.py": 60, "tests/torchhand/test_result.py": 59,
    "tests/torchhand/test_scene_swap.py": 34, "tests/torchhand/test_ycb_lift.py": 30,
    "tests/torchhand/test_fill.py": 28,
}


def pytest_collection_modifyitems(config, items):
    """Long files first (:data:`LONG_FILES`), the rest in collection order; tests keep their order in a file."""
    def weight(item):
        path = Path(str(item.fspath))
        return -LONG_FILES.get(path.relative_to(REPO).as_posix(), 0) if path.is_relative_to(REPO) else 0
    items.sort(key=weight)      # stable: equal weights keep their order
