"""A warm start for the step's contact LCP (Kry & Pai 2006 §7.1.3): the previous step's support, verified.

The LCP of one rollout over na active contacts with K = 2m + 1 pyramid directions has the variables
z = (beta (na K), lambda (na)) and w = M z + q = (nu (na K), sigma (na)) (:func:`~torchhand.kernels.contact_lcp.
build_kry_pai_lcp`): lambda_i enters only its own contact's tangential nu rows, with coefficient 1, and the sigma
rows (sigma_i = mu_i beta_i0 - sum_j beta_ij) hold no lambda. Between two steps the contact set and which pyramid
directions carry force change little, so the previous support usually is the new one. Given it:

1. beta's support S: the directions that carried force (beta > 0); lambda_i joins S where contact i's force lay on
   its cone's boundary (sigma_i ~ 0 with a tangential direction in S and mu_i > 0: a sliding contact, whose lambda
   is coupled to its nu rows);
2. z_S solves M_SS z_S = -q_S (least squares: where the pyramid directions of S are dependent, beta is not unique
   there), z = 0 elsewhere; a support that does not solve the LCP is corrected (:func:`solve_from_support`);
3. every other lambda_i whose sigma_i is 0 at z (a contact without force, or a frictionless one) is the least
   value that makes its tangential nu rows >= 0 (lambda_i is not unique there: any larger value also solves the
   LCP; the least one is the contact's relative tangential motion);
4. the answer is kept only if it solves the LCP: z >= 0, w >= 0 and ||min(z, w)||_inf <= tol, the step's tol
   being round-off (:data:`WARM_TOL`); otherwise the step pivots from scratch (Lemke), so the verdict never rests on
   the guess.

NumPy, float64, one problem.
"""

from __future__ import annotations

import numpy as np

__all__ = ["WARM_TOL", "support_guess", "solve_from_support"]

WARM_TOL = 1e-10
"""The step accepts a warm answer only within this tolerance relative to the LCP's largest entry: round-off, as a
pivoted answer's re-solved basis (a support that is right solves the LCP to the last digits; a looser test would
accept a wrong support's near-miss)."""


def support_guess(beta: np.ndarray, mu: np.ndarray, rel: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """The previous step's support: beta (na, K) > 0, and the sliding contacts (na,) bool (force on the cone's
    boundary within ``rel`` of mu_i beta_i0, a tangential direction carrying force, mu_i > 0)."""
    on = beta > 0
    sigma = mu * beta[:, 0] - beta[:, 1:].sum(-1)
    sliding = on[:, 0] & on[:, 1:].any(-1) & (mu > 0) & (np.abs(sigma) <= rel * mu * beta[:, 0])
    return on, sliding


def solve_from_support(M: np.ndarray, q: np.ndarray, na: int, K: int, on: np.ndarray, sliding: np.ndarray,
                       tol: float, rounds: int = 24) -> tuple[np.ndarray, float] | None:
    """(z (na K + na,), ||min(z, w)||_inf) solving LCP(M, q) from the support (``on`` (na, K), ``sliding`` (na,)) of
    :func:`support_guess` (module docstring), or None where no solution is reached within ``tol`` (absolute, on
    ||min(z, w)||_inf, with w >= -tol and z >= -tol before clipping). A support that does not solve it is corrected
    up to ``rounds`` times, block-pivoting style: the variables that came out negative leave it, and per contact the
    most negative slack brings its variable in."""
    S = np.concatenate([on.reshape(-1), sliding])
    for _ in range(rounds + 1):
        z = _on_support(M, q, S, na, K, tol)
        if z is None:
            return None
        w = M @ z + q
        low_z, low_w = S & (z < -tol), w < -tol
        if not low_z.any() and not low_w.any():
            z = np.maximum(z, 0.0)
            w = M @ z + q
            residual = float(np.abs(np.minimum(z, w)).max())
            return (z, residual) if w.min() >= -tol and residual <= tol else None
        S_next = (S & ~low_z) | _most_violated(w, low_w, na, K)
        if (S_next == S).all():
            return None
        S = S_next
    return None


def _most_violated(w: np.ndarray, low: np.ndarray, na: int, K: int) -> np.ndarray:
    """Per contact, only its most negative slack among ``low`` (its K nu rows and its sigma): the pyramid
    directions are linearly dependent, so bringing in every violated one at once makes M_SS singular."""
    nb = na * K
    per = np.concatenate([w[:nb].reshape(na, K), w[nb:, None]], 1)              # (na, K + 1)
    per = np.where(np.concatenate([low[:nb].reshape(na, K), low[nb:, None]], 1), per, np.inf)
    pick = np.zeros_like(per, dtype=bool)
    rows = np.isfinite(per).any(1)
    pick[rows, per[rows].argmin(1)] = True
    return np.concatenate([pick[:, :K].reshape(-1), pick[:, K]])


def _on_support(M: np.ndarray, q: np.ndarray, S: np.ndarray, na: int, K: int, tol: float) -> np.ndarray | None:
    """z with z_S solving M_SS z_S = -q_S, z = 0 elsewhere except the free lambdas (step 3 of the module
    docstring); None if M_SS is singular or z is not finite."""
    nb = na * K
    z = np.zeros(nb + na)
    if S.any():
        try:     # least squares: where the pyramid directions of S are dependent, beta is not unique there
            z[S] = np.linalg.lstsq(M[np.ix_(S, S)], -q[S], rcond=None)[0]
        except np.linalg.LinAlgError:
            return None
    if not np.isfinite(z).all():
        return None
    w = M @ z + q
    # lambda_i outside S may be > 0 where sigma_i = 0 and no tangential direction carries force (its nu rows
    # need not vanish): the least value that makes them >= 0
    free = ~S[nb:] & (np.abs(w[nb:]) <= tol) & ~(z[:nb].reshape(na, K)[:, 1:] > tol).any(-1)
    nu_t = w[:nb].reshape(na, K)[:, 1:]
    z[nb:] += np.where(free, np.maximum(0.0, -nu_t.min(-1)), 0.0)
    return z
