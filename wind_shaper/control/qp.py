"""The adaptive update's bounded steps: box-constrained quadratic programs.

``box_qp`` solves a small box-constrained QP (projected Newton); ``_bounded_lsq`` is the bounded,
Marquardt-damped Gauss-Newton step in PWM space built on it. ``_thrust_space_step`` solves the
step exactly in the per-fan thrusts a_j(U_j) of a ``FanBasis`` and maps it back to commands;
``_thrust_space_qp`` is the large-wall version (L-BFGS-B on the footprints' Gram matrix).

Units: commands U are fractions 0..1 of full PWM, one per fan; thrusts a_j [N]; residuals [N] at
the key points.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def _thrust_space_qp(basis, gains, residual, U_b, lo, hi, idx, damping=0.0) -> np.ndarray:
    """Large walls: argmin_d 1/2 d^T H d + c^T d over the thrust box (L-BFGS-B), with
    H = diag(g) S^T S diag(g) from the cached Gram matrix and c = diag(g) S^T residual; the
    commands are a^-1(a(U_b) + d)."""
    from scipy.optimize import minimize
    a_b, _ = basis.thrust(U_b)
    a_lo, _ = basis.thrust(lo)
    a_hi, _ = basis.thrust(hi)
    g = gains[idx]
    G = basis.gram[idx][:, idx].tocsr()
    rows = np.repeat(np.arange(len(idx)), np.diff(G.indptr))
    # Jacobi scaling d = x / sqrt(diag H): unit diagonal, so L-BFGS-B converges in far fewer steps
    diag = np.maximum(np.asarray(G.diagonal()) * g * g, 1e-12)
    p = 1.0 / np.sqrt(diag)
    gp = g * p
    H = sp.csr_matrix((G.data * gp[rows] * gp[G.indices], G.indices, G.indptr), shape=G.shape)
    H = (H + damping * sp.eye(len(idx))).tocsr()  # Marquardt: the scaled diagonal is 1
    c = gp * np.asarray(basis.shape[:, idx].T @ residual).ravel()
    scale = 1.0 / max(float(residual @ residual), 1e-12)

    def f(x):
        Hx = H @ x
        return scale * (0.5 * x @ Hx + c @ x), scale * (Hx + c)

    lb, ub = (a_lo[idx] - a_b[idx]) / p, (a_hi[idx] - a_b[idx]) / p
    sol = minimize(f, np.zeros(len(idx)), jac=True, method='L-BFGS-B',
                   bounds=np.column_stack([lb, np.maximum(ub, lb)]),
                   options={'maxiter': 500, 'ftol': 1e-12, 'gtol': 1e-9})
    t = a_b.copy()
    t[idx] += np.clip(sol.x, lb, ub) * p
    U = U_b.copy()
    U[idx] = basis.invert(t, lo, hi)[idx]
    return U


def _thrust_space_step(basis, Smat, residual, sw, U_b, lo, hi, idx, damping=0.0) -> np.ndarray:
    """argmin_U ||sw (residual + S (a(U) - a(U_b)))|| over lo <= U <= hi, solved as a bounded
    linear least-squares problem in t = a(U) and mapped back through a^-1."""
    a_b, _ = basis.thrust(U_b)
    a_lo, _ = basis.thrust(lo)
    a_hi, _ = basis.thrust(hi)
    dt = _bounded_lsq(Smat, None, residual, sw, idx, a_lo[idx] - a_b[idx], a_hi[idx] - a_b[idx], damping)
    t = a_b.copy()
    t[idx] += dt
    U = U_b.copy()
    U[idx] = basis.invert(t, lo, hi)[idx]
    return U


def _bounded_lsq(J, secant, residual, sw, idx, lb, ub, damping: float = 0.0, separable=None) -> np.ndarray:
    """argmin ||sw (J_idx du + D_idx du + residual)||^2 + damping sum_j ||sw A_j||^2 du_j^2 over
    lb <= du <= ub (the enabled fans idx; A = J + D): a bounded, Marquardt-damped
    Gauss-Newton step (the damping keeps nearly collinear fans from trading large opposite
    moves that the model cannot vouch for). separable: (h, g), each (len(idx),), adds
    sum_j (h_j du_j^2 + 2 g_j du_j) to the squared norm: a cost of each fan's own move
    (``AdaptiveUpdate.curve_risk``)."""
    A = J[:, idx]
    if secant is not None:
        A = A + secant.matrix()[:, idx]
    A = A * sw[:, None]
    b = -sw * residual
    lb = np.minimum(lb, ub)
    if np.all(ub - lb <= 0):
        return np.zeros(len(idx))
    H = A.T @ A
    H[np.diag_indices_from(H)] *= 1.0 + damping
    g = -(A.T @ b)
    if separable is not None:
        H[np.diag_indices_from(H)] += separable[0]
        g = g + separable[1]
    return box_qp(H, g, lb, ub)


def box_qp(H, g, lb, ub, iterations: int = 100) -> np.ndarray:
    """argmin 1/2 x^T H x + g^T x over lb <= x <= ub for a small symmetric positive
    (semi)definite H (n, n): projected Newton with an Armijo search along the projection arc
    (Bertsekas 1982). Exact for a strictly convex problem in a few iterations."""
    n = len(g)
    H = H + (1e-12 * max(float(np.trace(H)) / max(n, 1), 1e-300)) * np.eye(n)
    x = np.clip(np.zeros(n), lb, ub)
    f = 0.5 * x @ H @ x + g @ x
    for _ in range(iterations):
        grad = H @ x + g
        tiny = 1e-12 * (1.0 + np.abs(x))
        binding = ((x <= lb + tiny) & (grad > 0)) | ((x >= ub - tiny) & (grad < 0))
        free = ~binding
        d = np.zeros(n)
        if free.any():
            d[free] = -np.linalg.solve(H[np.ix_(free, free)], grad[free])
        t, moved = 1.0, False
        while t > 1e-10:
            x_t = np.clip(x + t * d, lb, ub)
            f_t = 0.5 * x_t @ H @ x_t + g @ x_t
            if f_t <= f + 1e-4 * grad @ (x_t - x):
                moved = True
                break
            t *= 0.5
        if not moved or np.max(np.abs(x_t - x)) <= 1e-13 * (1.0 + np.max(np.abs(x))):
            x = x_t if moved else x
            break
        x, f = x_t, f_t
    return x
