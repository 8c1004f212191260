"""Numeric code paths that are the same on every x86-64 CPU with AVX2 (the *portable* profile).

The same seed and node budget give byte-identical results only if every floating-point operation rounds the same
way. Three libraries pick their code path by CPU when they load, and a randomized search turns a last-bit
difference into another tree:

- torch's ATen vector kernels (AVX-512 on CPUs that have it, AVX2 otherwise): ``ATEN_CPU_CAPABILITY``; oneDNN's ISA:
  ``ONEDNN_MAX_CPU_ISA``;
- MKL (torch's BLAS and LAPACK) by CPU model and vendor: ``MKL_CBWR``. Its ``AVX2`` branch is documented for Intel
  CPUs only (on others MKL falls back to its automatic branch), so the portable profile uses ``COMPATIBLE``;
- OpenBLAS (NumPy's and SciPy's BLAS and LAPACK) by CPU model (Haswell, SkylakeX, Zen, ...): ``OPENBLAS_CORETYPE``;
  NumPy's own AVX-512 ufunc loops: ``NPY_DISABLE_CPU_FEATURES``.

Each is read once, when its library loads, so the profile must be in the environment before torch and NumPy are
imported. The command line does that itself (:func:`pin_for_command`, before it imports any of them);
``torchhand --numerics native ...`` or ``TORCHHAND_NUMERICS=native`` leaves the machine's fastest paths instead.
In Python, call :func:`reproducible` before importing torch or NumPy, or start the interpreter with the variables
that ``torchhand numerics --env`` prints. :func:`describe` tells which paths the running process uses; result
files record it in ``stats.json`` (``numerics``).

This module imports nothing but the standard library at load time.
"""

from __future__ import annotations

import functools
import os
import sys
from dataclasses import asdict, dataclass

from .errors import InputValueError, TorchhandError

__all__ = ["PORTABLE_ENV", "NumericsProfile", "describe", "pin_for_command", "portable_env", "reproducible"]

# NumPy < 2.4 names its AVX-512 dispatch targets by feature group (AVX512_SKX, ...); NumPy 2.4 groups them as the
# x86-64 microarchitecture level X86_V4 (plus AVX512_ICL, AVX512_SPR). Unknown names are ignored by either.
_NPY_AVX512 = ("X86_V4 AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL "
               "AVX512_SPR")

PORTABLE_ENV: dict[str, str] = {
    "ATEN_CPU_CAPABILITY": "avx2",
    "ONEDNN_MAX_CPU_ISA": "AVX2",
    "MKL_CBWR": "COMPATIBLE",
    "OPENBLAS_CORETYPE": "Haswell",
    "NPY_DISABLE_CPU_FEATURES": _NPY_AVX512,
}
"""The variables of the portable profile: AVX2 kernels for torch, MKL's vendor-independent branch, OpenBLAS's
Haswell kernels (AVX2 + FMA, what it picks on Zen too) and NumPy without its AVX-512 loops."""

MODES = ("portable", "native")
ENV_MODE = "TORCHHAND_NUMERICS"
_LIBRARIES = ("torch", "numpy", "scipy")


@dataclass(frozen=True)
class NumericsProfile:
    """The numeric code paths of the running process.

    ``mode``: ``"portable"`` (every variable of :data:`PORTABLE_ENV` in force), ``"native"`` (asked for) or
    ``"mixed"`` (some other setting: e.g. torch was imported before the profile could be set).
    ``torch_capability``: ATen's CPU kernels (``"AVX2"``, ``"AVX512"``, ``"DEFAULT"``, ...); ``mkl_cbwr`` and
    ``openblas_coretype`` as the environment set them (``None``: the library's own choice); ``openblas``: the core
    type each loaded OpenBLAS reports; ``numpy_avx512``: whether NumPy's AVX-512 loops are enabled."""

    mode: str
    torch_capability: str
    mkl_cbwr: str | None
    openblas_coretype: str | None
    openblas: tuple[str, ...]
    numpy_avx512: bool

    def as_dict(self) -> dict:
        d = asdict(self)
        d["openblas"] = list(self.openblas)
        return d


def cpu_has_avx2() -> bool:
    """True on an x86-64 CPU with AVX2 and FMA (Linux: ``/proc/cpuinfo``; elsewhere: assumed on x86-64)."""
    import platform

    if platform.machine().lower() not in ("x86_64", "amd64"):
        return False
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("flags"):
                    flags = set(line.split(":", 1)[1].split())
                    return {"avx2", "fma"} <= flags
    except OSError:
        pass
    return True


def portable_env() -> dict[str, str]:
    """The variables to set for the portable profile on this CPU (empty where it has no AVX2: the profile is an
    x86-64 AVX2 one, and a CPU without it keeps its own paths)."""
    return dict(PORTABLE_ENV) if cpu_has_avx2() else {}


def requested_mode(argv: list[str] | None = None) -> str:
    """``--numerics MODE`` (before the subcommand) or ``$TORCHHAND_NUMERICS``, default ``"portable"``."""
    mode = os.environ.get(ENV_MODE, "").strip() or "portable"
    args = list(argv or [])
    for i, a in enumerate(args):
        if a == "--numerics" and i + 1 < len(args):
            mode = args[i + 1]
        elif a.startswith("--numerics="):
            mode = a.split("=", 1)[1]
        elif not a.startswith("-"):
            break                                   # the subcommand: its own options follow
    if mode not in MODES:
        raise InputValueError(f"--numerics / ${ENV_MODE}: expected one of {', '.join(MODES)}, got {mode!r}")
    return mode


def _loaded() -> list[str]:
    return [m for m in _LIBRARIES if m in sys.modules]


def pin_for_command(argv: list[str] | None = None) -> str:
    """Set the portable profile's variables in this process' environment, before torch and NumPy load (the command
    line calls this first). Does nothing under ``native``, or when they are already loaded (the command then runs
    inside a caller's Python, e.g. a test, whose settings stay as they are). Returns the mode asked for."""
    mode = requested_mode(argv)
    if not _loaded():
        os.environ[ENV_MODE] = mode                 # for describe(), and for worker processes started later
        if mode == "portable":
            os.environ.update(portable_env())
    return mode


def reproducible() -> NumericsProfile:
    """Use the portable profile in this Python process. Call it before torch, NumPy or SciPy is imported (or start
    Python with the variables ``torchhand numerics --env`` prints); raises :class:`TorchhandError` if one of them is
    already loaded with other settings. Returns :func:`describe`."""
    want = portable_env()
    loaded = _loaded()
    if not loaded:
        os.environ.update(want)
        return describe()
    wrong = {k: v for k, v in want.items() if os.environ.get(k) != v}
    if wrong:
        raise TorchhandError(
            f"torchhand.reproducible(): {', '.join(loaded)} already loaded without {', '.join(sorted(wrong))}; call it "
            f"before importing them, or start Python with the variables of `torchhand numerics --env`")
    return describe()


def describe() -> NumericsProfile:
    """The numeric code paths this process uses (imports torch and threadpoolctl)."""
    import torch

    cap = str(torch.backends.cpu.get_cpu_capability())
    openblas: tuple[str, ...] = ()
    try:
        from threadpoolctl import threadpool_info

        openblas = tuple(sorted({str(i.get("architecture")) for i in threadpool_info()
                                 if i.get("internal_api") == "openblas"}))
    except Exception:  # pragma: no cover - threadpoolctl is a dependency; its probing is best effort
        pass
    numpy_avx512 = False
    if "numpy" in sys.modules:
        numpy_avx512 = _numpy_avx512(_numpy_features())
    want = portable_env()
    in_force = bool(want) and all(os.environ.get(k) == v for k, v in want.items()) and cap == "AVX2"
    mode = "portable" if in_force else ("native" if requested_mode() == "native" else "mixed")
    return NumericsProfile(mode=mode, torch_capability=cap, mkl_cbwr=os.environ.get("MKL_CBWR"),
                           openblas_coretype=os.environ.get("OPENBLAS_CORETYPE"), openblas=openblas,
                           numpy_avx512=numpy_avx512)


def _numpy_avx512(features: dict) -> bool:
    """Whether NumPy dispatches to AVX-512 loops: its X86_V4 (or AVX512_ICL/SPR) targets on NumPy >= 2.4, where the
    raw AVX512F flag stays set when they are disabled; its AVX512F feature before."""
    if "X86_V4" in features:
        return any(bool(features.get(k, False)) for k in ("X86_V4", "AVX512_ICL", "AVX512_SPR"))
    return bool(features.get("AVX512F", False))


def _numpy_features() -> dict:
    try:
        from numpy._core._multiarray_umath import __cpu_features__  # NumPy 2
    except ImportError:
        from numpy.core._multiarray_umath import __cpu_features__  # NumPy 1.x
    return dict(__cpu_features__)


@functools.lru_cache(maxsize=1)
def _recorded() -> NumericsProfile:
    return describe()


def record() -> dict:
    """:func:`describe` as the ``numerics`` entry of a ``stats.json`` (probed once per process: the code paths are
    fixed when the libraries load, and a run writes its partial stats.json after every solution)."""
    return _recorded().as_dict()
