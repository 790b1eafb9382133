"""Joint nonlinear refit of the baseline and the named effects (optimistix Gauss-Newton).

The residual is the per-axis AR-whitened, unit-variance output error of the full extended model
(:func:`jaxcal.diagnose.effects.model_output`) on the chosen rows; effects not named are held at
zero by a 0/1 mask (plus stiff penalty rows, so the normal equations stay well posed and one
compiled function serves every subset). Standard errors come from the whitened Jacobian at the
solution, ``cov = s^2 (J^T J)^-1`` with ``s^2 = RSS / (n - p)`` (1 if the AR noise model is right).
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from jaxcal.diagnose import effects as E
from jaxcal.diagnose.whiten import ARModel, fill_index, gap_ok

MAX_TAPS = 65


class RefitResult(NamedTuple):
    """``beta`` baseline, ``theta`` effects (zeros where masked), ``se_theta``/``se_beta`` standard
    errors, ``s2`` whitened residual variance, ``resid`` (N, 3) physical output error."""

    beta: np.ndarray
    theta: np.ndarray
    se_beta: np.ndarray
    se_theta: np.ndarray
    s2: float
    resid: np.ndarray


def _filters(ars: list[ARModel]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    taps = np.zeros((3, MAX_TAPS))
    sig = np.zeros(3)
    th = np.ones(3)
    for i, ar in enumerate(ars):
        taps[i, 0] = 1.0
        taps[i, 1 : 1 + len(ar.a)] = -ar.a
        sig[i] = ar.sigma
        th[i] = ar.theta
    return taps, sig, th


def _whiten(r, taps, sig, th):
    """IMA stage ``(1 - L)/(1 - th L)`` (scan) then the AR FIR, per axis (see whiten.py)."""
    n = r.shape[0]
    d = jnp.diff(r, axis=0, prepend=r[:1])

    def step(carry, dt_):
        y = dt_ + th * carry
        return y, y

    _, v = jax.lax.scan(step, jnp.zeros(3, r.dtype), d)
    v = jnp.where(th[None, :] < 1.0, v, r)
    cols = [jnp.convolve(v[:, i], taps[i], mode="full")[:n] / sig[i] for i in range(3)]
    return jnp.stack(cols, axis=1)


@partial(jax.jit, static_argnames=("kind", "sensor", "max_steps"))
def _refit(kind, sensor, phi0, mask, inp, y, fill_idx, row_w, taps, sig, th, max_steps=4):
    nb = E.N_BASE[kind]

    def unpack(phi):
        return phi[:nb], phi[nb:] * mask

    def resid(phi, _):
        beta, theta = unpack(phi)
        r = (y - E.model_output(kind, sensor, beta, theta, inp))[fill_idx]  # hold values over invalid rows
        rw = _whiten(r, taps, sig, th) * row_w
        pen = 1e3 * (1.0 - mask) * phi[nb:]
        return jnp.concatenate([rw.reshape(-1), pen])

    sol = optx.least_squares(resid, optx.GaussNewton(rtol=1e-6, atol=1e-9), phi0, max_steps=max_steps, throw=False)
    phi = sol.value
    jac = jax.jacfwd(lambda p: resid(p, None))(phi)
    rr = resid(phi, None)
    n_data = jnp.sum(row_w)
    return phi, jac, rr, n_data


def refit(kind: str, sensor: str, beta0, theta0, names: list[str], inp: E.Inputs, y: np.ndarray, rows: np.ndarray, ars: list[ARModel]) -> RefitResult:
    """Fit baseline + effects ``names`` jointly on ``rows`` (bool (N,)) from ``(beta0, theta0)``."""
    mask = E.effect_mask(sensor, names)
    taps, sig, th = _filters(ars)
    row_w = np.stack([gap_ok(rows, ar.memory) for ar in ars], 1).astype(np.float64)
    nb = E.N_BASE[kind]
    with jax.enable_x64(True):
        jinp = E.Inputs(*[jnp.asarray(a, jnp.float64) for a in inp])
        phi0 = jnp.asarray(np.concatenate([beta0, np.asarray(theta0) * mask]), jnp.float64)
        phi, jac, rr, n_data = _refit(
            kind, sensor, phi0, jnp.asarray(mask), jinp, jnp.asarray(y, jnp.float64),
            jnp.asarray(fill_index(rows)), jnp.asarray(row_w), jnp.asarray(taps), jnp.asarray(sig), jnp.asarray(th),
        )
        phi = np.asarray(phi)
        jac = np.asarray(jac)
        rr = np.asarray(rr)
        beta, theta = phi[:nb], phi[nb:] * mask
        resid = np.asarray(y - E.model_output(kind, sensor, jnp.asarray(beta), jnp.asarray(theta), jinp))
    n3 = 3 * len(y)
    active = np.concatenate([np.ones(nb, bool), mask > 0])
    ja = jac[:n3][:, active]
    n_eff = float(n_data)
    s2 = float(rr[:n3] @ rr[:n3]) / max(n_eff - active.sum(), 1.0)
    jtj = ja.T @ ja
    sc = np.sqrt(np.clip(np.diag(jtj), 1e-300, None))
    cov = np.linalg.pinv(jtj / sc[:, None] / sc[None, :]) / sc[:, None] / sc[None, :] * s2
    se = np.zeros(len(phi))
    se[active] = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return RefitResult(beta, theta, se[:nb], se[nb:], s2, resid)
