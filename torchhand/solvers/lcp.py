"""Linear complementarity problems: the front door :func:`solve`, the batched solve with an exact fallback,
test-problem builders, Siconos reader.

:func:`solve` takes the backend by name: ``"pgs"`` is :func:`solve_lcp` (torch, batched: ``M`` (B, n, n), ``q``
(B, n); returns :class:`LCPSolution`), ``"lemke"`` is :func:`torchhand.solvers._lemke.lemke` (one problem, NumPy
float64: ``M`` (n, n), ``q`` (n,); returns its ``LemkeResult``); options pass through unchanged.

:func:`solve_lcp` is the batched solver for standard LCPs (x >= 0, w = M x + q >= 0, x^T w = 0) of a batch: it
validates at the boundary (raising :class:`~torchhand.errors.TorchhandError` subclasses), runs the batched
projected Gauss-Seidel kernel :func:`torchhand.kernels.lcp.solve_lcp_pgs`, and hands the small problems PGS could
not finish (MAX_ITERATIONS, a diverged iterate, or a zero/negative diagonal PGS cannot divide by) to Lemke's method
(:func:`torchhand.solvers._lemke.lemke`, CPU float64), which either solves them exactly or reports ray termination
(UNBOUNDED). :func:`random_lcp` builds the seeded test and benchmark problems; :func:`read_siconos_lcp` reads the
Siconos LCP test files.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from ..conventions import check_tensor
from ..errors import FileFormatError, InputTypeError, InputValueError, MissingFileError, ShapeError
from ..kernels.lcp import LCPResult, lcp_residual, lcp_tolerances, solve_lcp_pgs
from ..kernels.status import SolverStatus
from ._lemke import lemke

__all__ = ["BACKENDS", "solve", "LCPSolution", "LCPProblem", "solve_lcp", "random_lcp", "read_siconos_lcp"]

BACKENDS = ("pgs", "lemke")


@dataclass(frozen=True)
class LCPSolution:
    """Result of :func:`solve_lcp` for B problems of size n.

    x:          solution, (B, n), >= 0; 0 at padded entries
    w:          M x + q, (B, n); 0 at padded entries
    residual:   ||min(x, w)||_inf over the active entries, (B,); +inf for INVALID_INPUT
    status:     (B,), int8 values of :class:`~torchhand.kernels.status.SolverStatus`
    iterations: PGS sweeps, (B,), int32
    pivots:     Lemke pivots spent on the problem, (B,), int64; 0 where Lemke did not run
    lemke:      (B,) bool, True where the returned answer (or the UNBOUNDED verdict) comes from Lemke
    """

    x: torch.Tensor
    w: torch.Tensor
    residual: torch.Tensor
    status: torch.Tensor
    iterations: torch.Tensor
    pivots: torch.Tensor
    lemke: torch.Tensor


class LCPProblem(NamedTuple):
    """Problems from :func:`random_lcp`.

    M:      LCP matrices, (B, n, n)
    q:      LCP vectors, (B, n)
    x_star: a planted solution, (B, n), >= 0 (the solution when M is positive definite)
    """

    M: torch.Tensor
    q: torch.Tensor
    x_star: torch.Tensor


def solve_lcp(M: torch.Tensor, q: torch.Tensor, *, x0: torch.Tensor | None = None,
              mask: torch.Tensor | None = None, tol: float | None = None, max_iters: int | None = None,
              check_every: int = 10, omega: float = 1.0, subspace: bool = False, mixed: bool = False,
              lemke_max_n: int = 64, max_pivots: int | None = None) -> LCPSolution:
    """Solve a batch of standard LCPs with PGS, finishing unfinished small problems exactly with Lemke.

    Args:
        M: LCP matrices, (B, n, n)
        q: LCP vectors, (B, n)
        x0: warm start, (B, n); mask: active entries, (B, n) bool (padding False)
        tol, max_iters, check_every, omega, subspace, mixed: passed to
            :func:`torchhand.kernels.lcp.solve_lcp_pgs`
        lemke_max_n: problems with at most this many active entries go to Lemke when PGS fails (0 = never)
        max_pivots: Lemke's pivot limit per problem (default ``max(1000, 50 n)``)

    Returns:
        :class:`LCPSolution`. A problem is CONVERGED when PGS or Lemke reached ``tol``; UNBOUNDED when Lemke
        terminated on a ray (no solution for copositive-plus M, e.g. positive semidefinite M) or PGS diverged and
        Lemke did not run; MAX_ITERATIONS or INVALID_INPUT otherwise.

    Raises:
        ShapeError, InputTypeError, InputValueError naming the argument.
    """
    check_tensor(M, "M", (None, "n", "n"))
    if M.shape[1] != M.shape[2]:
        raise ShapeError(f"M: expected shape (B, n, n), got {tuple(M.shape)}")
    B, n, _ = M.shape
    check_tensor(q, "q", (B, n))
    if x0 is not None:
        check_tensor(x0, "x0", (B, n))
    if mask is not None:
        check_tensor(mask, "mask", (B, n), floating=False)
        if mask.dtype != torch.bool:
            raise InputTypeError(f"mask: expected a bool tensor, got dtype {mask.dtype}")
    for name, t in (("q", q), ("x0", x0), ("mask", mask)):
        if t is not None and t.device != M.device:
            raise InputValueError(f"{name}: expected device {M.device} like M, got {t.device}")
    for name, t in (("q", q), ("x0", x0)):
        if t is not None and t.dtype != M.dtype:
            raise InputTypeError(f"{name}: expected dtype {M.dtype} like M, got {t.dtype}")
    if M.dtype not in (torch.float32, torch.float64):
        raise InputTypeError(f"M: expected torch.float32 or torch.float64, got {M.dtype}")
    try:
        res: LCPResult = solve_lcp_pgs(M, q, x0=x0, mask=mask, tol=tol, max_iters=max_iters,
                                       check_every=check_every, omega=omega, subspace=subspace, mixed=mixed)
    except ValueError as err:                   # option values (omega, check_every, max_iters)
        raise InputValueError(str(err)) from None
    tol = lcp_tolerances(M.dtype).tol if tol is None else float(tol)

    x, w, residual, status = res.x.clone(), res.w.clone(), res.residual.clone(), res.status.clone()
    pivots = torch.zeros(B, dtype=torch.int64, device=M.device)
    used = torch.zeros(B, dtype=torch.bool, device=M.device)
    act = torch.ones(B, n, dtype=torch.bool, device=M.device) if mask is None else mask
    finite = torch.isfinite(torch.where(act[:, :, None] & act[:, None, :], M, 0.0)).flatten(1).all(-1)
    finite &= torch.isfinite(torch.where(act, q, 0.0)).all(-1)
    todo = (status != int(SolverStatus.CONVERGED)) & finite & (act.sum(-1) <= lemke_max_n)
    for b in todo.nonzero().flatten().tolist():
        idx = act[b].nonzero().flatten()
        Mb = M[b][idx][:, idx].detach().to("cpu", torch.float64).numpy()
        qb = q[b][idx].detach().to("cpu", torch.float64).numpy()
        out = lemke(Mb, qb, max_pivots=max_pivots)
        pivots[b] = out.pivots
        if out.status == SolverStatus.UNBOUNDED:
            status[b] = int(SolverStatus.UNBOUNDED)
            used[b] = True
            continue
        if out.status != SolverStatus.CONVERGED:
            continue
        xb = torch.zeros(n, dtype=M.dtype, device=M.device)
        xb[idx] = torch.as_tensor(out.x, dtype=M.dtype, device=M.device)
        Mb_act = torch.where(act[b][:, None] & act[b][None, :], M[b], 0.0)
        wb = torch.where(act[b], Mb_act @ xb + q[b], 0.0)
        rb = lcp_residual(xb[None], wb[None], act[b][None])[0]
        if bool(rb <= tol) or bool(rb <= residual[b]) or status[b] == int(SolverStatus.INVALID_INPUT):
            x[b], w[b], residual[b], used[b] = xb, wb, rb, True
            status[b] = int(SolverStatus.CONVERGED) if bool(rb <= tol) else int(SolverStatus.MAX_ITERATIONS)
    return LCPSolution(x, w, residual, status, res.iterations, pivots, used)


def random_lcp(B: int, n: int, *, generator: torch.Generator, kind: str = "pd", dtype: torch.dtype = torch.float64,
               device: str | torch.device = "cpu", ridge: float = 0.1) -> LCPProblem:
    """Seeded random LCPs with a planted solution (for tests and benchmarks).

    A standard-normal z gives x* = max(z, 0), w* = max(-z, 0) (complementary, about half the entries active) and
    q = w* - M x*, so x* solves LCP(M, q). Kinds of M (B, n, n):

    - ``"pd"``: A A^T / n + ridge I with A (n, n) standard normal: symmetric positive definite, condition number
      about 40 for n = 30 and ridge 0.1 (the solution is unique: x*)
    - ``"psd"``: A A^T / n with A (n, n // 2): symmetric positive semidefinite of rank n // 2 (positive diagonal)
    - ``"monotone"``: the ``"pd"`` matrix plus a skew-symmetric part S - S^T, S (n, n) standard normal / sqrt(n):
      non-symmetric with positive definite symmetric part (x* unique)

    Returns:
        :class:`LCPProblem` (M, q, x_star), float ``dtype`` on ``device``; drawn in float64 on the CPU from
        ``generator``.
    """
    if kind not in ("pd", "psd", "monotone"):
        raise InputValueError(f"kind: expected 'pd', 'psd' or 'monotone', got {kind!r}")
    if B < 0 or n < 0:
        raise InputValueError(f"B, n: expected non-negative sizes, got {B}, {n}")
    f64 = torch.float64
    k = max(n // 2, 1) if kind == "psd" else n
    A = torch.randn(B, n, k, generator=generator, dtype=f64)
    M = A @ A.transpose(1, 2) / max(n, 1)
    if kind != "psd":
        M = M + ridge * torch.eye(n, dtype=f64)
    if kind == "monotone":
        S = torch.randn(B, n, n, generator=generator, dtype=f64) / max(n, 1) ** 0.5
        M = M + S - S.transpose(1, 2)
    z = torch.randn(B, n, generator=generator, dtype=f64)
    x_star, w_star = z.clamp_min(0), (-z).clamp_min(0)
    q = w_star - (M @ x_star[..., None]).squeeze(-1)
    return LCPProblem(*(t.to(device=device, dtype=dtype) for t in (M, q, x_star)))


def read_siconos_lcp(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a Siconos LCP test file (``numerics/src/LCP/test/data/*.dat``).

    Format: n, storage (0 dense, 1 sparse block), then the matrix, then q (n numbers); trailing comment lines
    are ignored. Dense: ``size0 size1`` twice, then the n x n entries column by column. Sparse block: ``size0
    size1``, nbblocks, the block-row and block-column counts, their cumulative sizes, the compressed row pointers
    and column indices of the blocks, then each block as its index followed by its entries column by column.

    Returns:
        (M (n, n), q (n,)) float64 arrays. Raises MissingFileError or FileFormatError naming the file.
    """
    p = Path(path)
    if not p.is_file():
        raise MissingFileError(f"path: LCP file not found: {p}")
    toks: list[float] = []
    for line in p.read_text().splitlines():
        try:
            toks.extend(float(t) for t in line.split())
        except ValueError:
            break                                                   # comments after the data
    try:
        return _parse_siconos(toks)
    except (IndexError, ValueError) as err:
        raise FileFormatError(f"{p}: not a Siconos LCP file ({err})") from None


def _parse_siconos(toks: list[float]) -> tuple[np.ndarray, np.ndarray]:
    def take(k: int) -> list[float]:
        nonlocal pos
        if pos + k > len(toks):
            raise ValueError(f"expected {k} more numbers at position {pos}, the file has {len(toks)}")
        out = toks[pos:pos + k]
        pos += k
        return out

    pos = 0
    n, storage = (int(v) for v in take(2))
    size0, size1 = (int(v) for v in take(2))
    if (size0, size1) != (n, n):
        raise ValueError(f"matrix size {size0} x {size1} does not match n = {n}")
    if storage == 0:
        take(2)                                                     # the dense header repeats the sizes
        M = np.array(take(n * n)).reshape(n, n, order="F")
    elif storage == 1:
        _, nb0, nb1 = (int(v) for v in take(3))
        rows = [0] + [int(v) for v in take(nb0)]                    # cumulative block sizes
        cols = [0] + [int(v) for v in take(nb1)]
        filled1, filled2 = (int(v) for v in take(2))
        ptr = [int(v) for v in take(filled1)]
        ind = [int(v) for v in take(filled2)]
        M = np.zeros((n, n))
        for br in range(filled1 - 1):
            for j in range(ptr[br], ptr[br + 1]):
                if int(take(1)[0]) != j:
                    raise ValueError(f"block {j} out of order")
                bc = ind[j]
                h, w = rows[br + 1] - rows[br], cols[bc + 1] - cols[bc]
                M[rows[br]:rows[br + 1], cols[bc]:cols[bc + 1]] = np.array(take(h * w)).reshape(h, w, order="F")
    else:
        raise ValueError(f"unknown storage type {storage}")
    q = np.array(take(n))
    return M, q


def solve(M, q, *, backend: str, **options):
    """Solve LCP(M, q) with the named backend: ``"pgs"`` (:func:`solve_lcp`, a batch) or ``"lemke"``
    (:func:`torchhand.solvers._lemke.lemke`, one problem); see the module docstring.

    Raises:
        InputValueError: an unknown backend or option (the message names the choices); the backend's own errors.
    """
    from .qp import check_options

    fns = {"pgs": solve_lcp, "lemke": lemke}
    if backend not in fns:
        raise InputValueError(f"backend: expected one of {', '.join(map(repr, BACKENDS))}, got {backend!r}")
    params = inspect.signature(fns[backend]).parameters
    positional = [n for n, p in params.items() if p.kind is inspect.Parameter.POSITIONAL_OR_KEYWORD][2:]
    options_ok = {k: v for k, v in options.items() if k not in positional}
    check_options(fns[backend], f"backend {backend!r}", options_ok)
    return fns[backend](M, q, **options)
