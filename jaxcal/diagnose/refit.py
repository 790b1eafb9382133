"""Joint nonlinear refit of the baseline and the named effects (optimistix Levenberg-Marquardt).

The residual is the per-axis AR-whitened, unit-variance output error of the full extended model
(:func:`jaxcal.diagnose.effects.model_output`) on the chosen rows; effects not named are held at
zero by a 0/1 mask (plus stiff penalty rows, so the normal equations stay well posed and one
compiled function serves every subset).

Convergence: when a regressor is computed from a noisy reference (errors in variables, e.g. the
time-offset regressor ``-d(reference)/dt`` of a twice-differentiated mocap position), the
Gauss-Newton curvature ``J^T J`` overstates the true curvature of the objective (it counts the
regressor's own noise), so each step covers only part of the way and Gauss-Newton converges
linearly. The minimiser itself stays consistent (a band-limited shift does not change the
whitened energy of the reference noise), so the solver runs to convergence (``max_steps``
default 128) rather than a fixed few steps. Levenberg-Marquardt, not plain Gauss-Newton: under a
random-walk noise model the whitening nearly annihilates the bias columns, the undamped normal
equations are singular and a Gauss-Newton solve fails on its first step (it then returned the
starting point unchanged).

Standard errors, two of them, and the larger is reported per parameter:

* model-based ``cov = s^2 (J^T J)^-1`` with ``s^2 = RSS / (n - p)`` (right when the AR noise
  model is right and the regressors are exact);
* block sandwich (cluster-robust over the cross-validation time blocks): ``H^-1 (K/(K-1)
  sum_k g_k g_k^T) H^-1`` with ``g_k`` the gradient of ``RSS/2`` from block ``k`` alone and ``H``
  the exact Hessian of ``RSS/2`` (autodiff), which does not count regressor noise as information.
  It stays honest under errors in variables and residual colour the AR model missed; with only
  ``K`` blocks it is itself uncertain (about ``K - 1`` degrees of freedom), hence the maximum.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from jaxcal.diagnose import effects as E
from jaxcal.diagnose.whiten import ARModel, fill_index, gap_ok, local_level_gains
from jaxcal.precision import float64

__all__ = [
    "MAX_TAPS",
    "RefitResult",
    "block_sandwich_cov",
    "refit",
    "whitening_filters",
    "whiten_residual",
]

MAX_TAPS = 65


class RefitResult(NamedTuple):
    """``beta`` baseline, ``theta`` effects (zeros where masked), ``se_beta``/``se_theta`` reported
    standard errors (the larger of model-based and block sandwich), ``s2`` whitened residual
    variance, ``resid`` (N, 3) physical output error; ``se_model_theta``/``se_block_theta`` the two
    standard errors separately, ``n_steps`` solver steps taken (NaN / 0 where not refitted)."""

    beta: np.ndarray
    theta: np.ndarray
    se_beta: np.ndarray
    se_theta: np.ndarray
    s2: float
    resid: np.ndarray
    se_model_theta: np.ndarray | None = None
    se_block_theta: np.ndarray | None = None
    n_steps: int = 0
    cov: np.ndarray | None = None  # (B+P, B+P) over [beta, theta]: correlations of the sandwich (else model), scales of se
    n_downweighted: int = 0  # whitened rows given a Huber weight below 1


def whitening_filters(ars: list[ARModel], n: int) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
    """AR taps (3, MAX_TAPS), innovation sd (3,) and the random-walk stage as per-sample gains
    ``K`` and inverse innovation sd factors ``sfi`` (both (n, 3); ``K = 0, sfi = 1``: identity)."""
    taps = np.zeros((3, MAX_TAPS))
    sig = np.zeros(3)
    K, sfi = np.zeros((n, 3)), np.ones((n, 3))
    for i, ar in enumerate(ars):
        taps[i, 0] = 1.0
        taps[i, 1 : 1 + len(ar.a)] = -ar.a
        sig[i] = ar.sigma
        if ar.lam > 0:
            k, sf = local_level_gains(float(ar.lam), n)
            K[:, i], sfi[:, i] = k, 1.0 / sf
    return taps, sig, (K, sfi)


def whiten_residual(r, taps, sig, ll):
    """Whitened residual of ``r`` (N, 3) with the filters of :func:`whitening_filters`: random-walk stage (exact diffuse local-level innovations, scan; identity where ``K = 0``)
    then the AR FIR, per axis (the same filter as :func:`jaxcal.diagnose.whiten.apply_filter`)."""
    n = r.shape[0]
    K, sfi = ll

    def step(m, xs):
        x, k, s = xs
        v = x - m
        return m + k * v, v * s

    _, v = jax.lax.scan(step, jnp.zeros(3, r.dtype), (r, K, sfi))
    cols = [jnp.convolve(v[:, i], taps[i], mode="full")[:n] / sig[i] for i in range(3)]
    return jnp.stack(cols, axis=1)


@partial(jax.jit, static_argnames=("kind", "sensor", "max_steps"))
def _refit(kind, sensor, phi0, mask, inp, y, fill_idx, row_w, taps, sig, th, max_steps=128):
    nb = E.N_BASE[kind]

    def unpack(phi):
        return phi[:nb], phi[nb:] * mask

    def white(phi):
        beta, theta = unpack(phi)
        r = (y - E.model_output(kind, sensor, beta, theta, inp))[fill_idx]  # hold values over invalid rows
        return whiten_residual(r, taps, sig, th) * row_w

    def resid(phi, _):
        pen = 1e3 * (1.0 - mask) * phi[nb:]
        return jnp.concatenate([white(phi).reshape(-1), pen])

    sol = optx.least_squares(resid, optx.LevenbergMarquardt(rtol=1e-8, atol=1e-12), phi0, max_steps=max_steps, throw=False)
    phi = sol.value
    jac = jax.jacfwd(lambda p: resid(p, None))(phi)
    hess = jax.hessian(lambda p: 0.5 * jnp.sum(resid(p, None) ** 2))(phi)
    rr = resid(phi, None)
    n_data = jnp.sum(row_w)
    return phi, jac, hess, rr, n_data, sol.stats["num_steps"]


def scaled_inv(a: np.ndarray) -> np.ndarray:
    """Pseudo-inverse of a symmetric ``a`` after scaling it to unit diagonal (parameters of very
    different units: seconds, metres, ppm), scaled back."""
    sc = np.sqrt(np.clip(np.abs(np.diag(a)), 1e-300, None))
    return np.linalg.pinv(a / sc[:, None] / sc[None, :]) / sc[:, None] / sc[None, :]


def block_sandwich_cov(jac: np.ndarray, rr: np.ndarray, hess: np.ndarray, row_block: np.ndarray) -> np.ndarray:
    """Cluster-robust covariance ``H^-1 (K/(K-1) sum_k g_k g_k^T) H^-1`` (see module docstring).

    Args:
        jac: (M, P) Jacobian of the whitened residual rows.
        rr: (M,) whitened residual at the solution.
        hess: (P, P) Hessian of ``|r|^2 / 2`` (falls back to ``J^T J`` if not positive definite).
        row_block: (M,) block id of each row (rows of one block are summed into one score).
    """
    kb = int(row_block.max()) + 1
    g = np.stack([jac[row_block == k].T @ rr[row_block == k] for k in range(kb)])
    g = g - g.mean(0)  # the blocks' scores sum to ~0 at the optimum; centring removes the rest
    meat = g.T @ g * kb / max(kb - 1, 1)
    h = hess
    h = 0.5 * (h + h.T)
    d = np.sqrt(np.clip(np.abs(np.diag(h)), 1e-300, None))
    if not np.all(np.isfinite(h)) or np.linalg.eigvalsh(h / d[:, None] / d[None, :]).min() < -1e-9:
        h = jac.T @ jac
    hi = scaled_inv(h)
    return hi @ meat @ hi


@float64
def refit(kind: str, sensor: str, beta0, theta0, names: list[str], inp: E.Inputs, y: np.ndarray, rows: np.ndarray,
          ars: list[ARModel], block: np.ndarray | None = None, max_steps: int = 128, huber: float | None = 3.0) -> RefitResult:
    """Fit baseline + effects ``names`` jointly on ``rows`` from ``(beta0, theta0)``.

    Huber step: after the least-squares solve, whitened rows whose residual exceeds ``huber`` robust
    standard deviations (1.4826 x median absolute residual) get the Huber weight ``huber sd / |r|``
    and the fit is solved once more (the block sandwich keeps the standard errors honest under the
    weights). On Gaussian noise about 0.3 % of rows are touched.

    Args:
        kind: baseline, ``"diag"`` or ``"affine"`` (static in the compiled solve).
        sensor: ``"acc"`` or ``"gyr"`` (static in the compiled solve).
        beta0: (B,) starting baseline parameters.
        theta0: (P,) starting effect parameters (masked to ``names``).
        names: the effects fitted; the others are held at zero.
        inp: reference signals.
        y: (N, 3) sensor output (physical units).
        rows: (N,) bool, the rows fitted.
        ars: per-axis noise models (3), the whitening.
        block: (N,) int time-block ids for the block-sandwich standard error; None: model-based only.
        max_steps: Levenberg-Marquardt step cap (static).
        huber: outlier threshold in robust sd (mocap glitches, shocks); None: plain least squares.
    """
    mask = E.effect_mask(sensor, names)
    taps, sig, th = whitening_filters(ars, len(y))
    row_w = np.stack([gap_ok(rows, ar.memory) for ar in ars], 1).astype(np.float64)
    nb = E.N_BASE[kind]
    jinp = E.as_jax(inp)
    phi0 = jnp.asarray(np.concatenate([beta0, np.asarray(theta0) * mask]), jnp.float64)
    args = (jnp.asarray(mask), jinp, jnp.asarray(y, jnp.float64), jnp.asarray(fill_index(rows)))
    filt = (jnp.asarray(taps), jnp.asarray(sig), tuple(jnp.asarray(a) for a in th))
    phi, jac, hess, rr, n_data, n_steps = _refit(kind, sensor, phi0, *args, jnp.asarray(row_w), *filt, max_steps=max_steps)
    n_down = 0
    if huber is not None:
        # one iteratively-reweighted pass: whitened rows beyond huber x robust sd get Huber weights
        u = np.asarray(rr)[: 3 * len(y)].reshape(len(y), 3)
        on = row_w > 0
        sd = 1.4826 * float(np.median(np.abs(u[on]))) if on.any() else 0.0
        if sd > 0:
            w = np.minimum(1.0, huber * sd / np.maximum(np.abs(u), 1e-300))
            n_down = int(np.sum(on & (w < 1.0)))
            if n_down:
                phi, jac, hess, rr, n_data, n_steps = _refit(kind, sensor, phi, *args, jnp.asarray(row_w * np.sqrt(w)), *filt,
                                                             max_steps=max_steps)
    phi, jac, hess, rr = (np.asarray(a) for a in (phi, jac, hess, rr))
    beta, theta = phi[:nb], phi[nb:] * mask
    _, resid = E.linearized_baseline(kind, sensor, jnp.asarray(beta), jnp.asarray(theta), jinp, jnp.asarray(y, jnp.float64))
    resid = np.asarray(resid)
    n3 = 3 * len(y)
    active = np.concatenate([np.ones(nb, bool), mask > 0])
    ja = jac[:n3][:, active]
    n_eff = float(n_data)
    s2 = float(rr[:n3] @ rr[:n3]) / max(n_eff - active.sum(), 1.0)
    cov = scaled_inv(ja.T @ ja) * s2
    se_m = np.zeros(len(phi))
    se_m[active] = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    se = se_m.copy()
    se_b = None
    if block is not None and int(np.max(block)) >= 2:
        rb = np.repeat(np.asarray(block), 3)
        cb = block_sandwich_cov(ja, rr[:n3], hess[np.ix_(active, active)], rb)
        se_b = np.zeros(len(phi))
        se_b[active] = np.sqrt(np.clip(np.diag(cb), 0.0, None))
        se = np.maximum(se_m, se_b)
    corr_src = cov if se_b is None else cb
    d = np.sqrt(np.clip(np.diag(corr_src), 0.0, None))
    inv = np.divide(1.0, d, out=np.zeros_like(d), where=d > 1e-150)
    corr = np.clip(corr_src * inv[:, None] * inv[None, :], -1.0, 1.0)
    sa = se[active]
    cov_full = np.zeros((len(phi), len(phi)))
    cov_full[np.ix_(active, active)] = corr * sa[:, None] * sa[None, :]
    return RefitResult(beta, theta, se[:nb], se[nb:], s2, resid, se_m[nb:], None if se_b is None else se_b[nb:], int(n_steps), cov_full, n_down)
