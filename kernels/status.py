"""Per-problem solver status shared by every batched solver kernel.

A solver returns ``status (B,)`` as an int8 tensor of :class:`SolverStatus` values, decided per problem with masks
(never from a batch mean). ``SolverStatus(int(s)).message`` says what it means and what to do about it.
"""

from __future__ import annotations

import enum

import torch

__all__ = ["SolverStatus", "status_tensor"]


class SolverStatus(enum.IntEnum):
    CONVERGED = 0
    INFEASIBLE = 1
    MAX_ITERATIONS = 2
    INVALID_INPUT = 3
    UNBOUNDED = 4

    @property
    def message(self) -> str:
        return _MESSAGES[self]


_MESSAGES = {
    SolverStatus.CONVERGED: "converged: the residual is below the tolerance",
    SolverStatus.INFEASIBLE: "infeasible: no point satisfies the constraints (a certificate was found); "
                             "the problem, not the solver, must change",
    SolverStatus.MAX_ITERATIONS: "stopped at max_iters before reaching the tolerance; raise max_iters, loosen tol, "
                                 "or warm-start from a nearby solution",
    SolverStatus.INVALID_INPUT: "invalid input: NaN/inf or inconsistent data in this problem; nothing was solved",
    SolverStatus.UNBOUNDED: "unbounded or no solution (e.g. ray termination of a pivoting method); "
                            "check the problem's data",
}


def status_tensor(value: SolverStatus, shape, device=None) -> torch.Tensor:
    """A status tensor filled with ``value``, int8."""
    return torch.full(tuple(shape), int(value), dtype=torch.int8, device=device)
