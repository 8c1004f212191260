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
