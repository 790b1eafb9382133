"""Fisher information and Cramer-Rao bounds for the self-calibration protocol of Dataset 2.

For a Gaussian measurement model ``z = h(phi) + n``, ``n ~ N(0, Sigma)``, the Fisher information
is ``F = J^T Sigma^{-1} J`` with ``J = dh/dphi`` (:func:`gaussian_fisher`). When ``phi = (theta,
nu)`` holds nuisance parameters ``nu``, the information on ``theta`` alone is the Schur complement
``F_tt - F_tn F_nn^{-1} F_nt`` (:func:`schur_marginal`), and any unbiased estimator has
``Cov(theta_hat) >= F^{-1}`` (the Cramer-Rao bound).

The protocol (:func:`protocol_fisher`): each sequence ``m`` is measured as spec-converted
accelerometer readings ``u_a,n = K_a^{-1} (Phi_n(w_c)^T f_0,m + e_a) + n_a`` where ``w_c`` is the
calibrated gyroscope reading ``K_g u_g,n - e_g`` (the same model as :mod:`jaxcal.online`; the
calibration parameters ``theta`` use the :func:`jaxcal.online.unpack` layout) and the start
direction ``f_0,m`` is a 2-dof nuisance. Gyroscope noise enters as errors in the variables: with
``u_g = u_g,true + n_g`` the accelerometer residuals get the extra covariance ``H_g Sigma_g
H_g^T`` (``H_g = d u_a / d u_g``), so ``Sigma_m = sigma_a^2 I + sigma_g^2 H_g H_g^T`` (a dense
3N x 3N matrix per sequence). This is the Fisher information of the accelerometer readings
*conditional on* the gyroscope readings, linearised at the truth: it ignores the (weak)
information in the gyroscope readings' own distribution and treats rounding as white noise of
variance 1/12 LSB^2 (add it to ``sigma``), so the bound is approximate at the 1e-2 level.

Mapping to the test error (:func:`expected_error`): the calibration-induced error of test sample
``l`` is, to first order, ``G_l dtheta`` with ``G_l = d cal(theta, u_l) / d theta`` and
``dtheta ~ N(0, F^{-1})`` for an efficient estimator; ``E|q_l + G_l dtheta|`` (``q_l`` the test
sample's own error with the true parameters, e.g. its rounding) is evaluated by Monte Carlo over
``dtheta`` (exact for the linearised Gaussian model up to Monte Carlo error).
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from jaxcal.online import predict_acc_readings


def gaussian_fisher(
    jac: Float[Array, "K P"], cov: Float[Array, "K K"] | None = None, sigma: float | Float[Array, ""] = 1.0
) -> Float[Array, "P P"]:
    """``J^T Sigma^{-1} J``; ``Sigma = cov`` if given, else ``sigma^2 I``."""
    if cov is None:
        return jac.T @ jac / sigma**2
    chol = jnp.linalg.cholesky(cov)
    w = jax.scipy.linalg.solve_triangular(chol, jac, lower=True)
    return w.T @ w


def schur_marginal(fisher: Float[Array, "P+Q P+Q"], p: int) -> Float[Array, "P P"]:
    """Information on the first ``p`` parameters with the remaining (nuisance) ones unknown."""
    a, b, d = fisher[:p, :p], fisher[:p, p:], fisher[p:, p:]
    out = a - b @ jnp.linalg.solve(d, b.T)
    return 0.5 * (out + out.T)


def predicted_acc(
    theta: Float[Array, "P"],
    delta: Float[Array, "2"],
    f0: Float[Array, "3"],
    u_gyr: Float[Array, "N 3"],
    dt: float | Float[Array, ""],
    kind: str,
) -> Float[Array, "3N"]:
    """Noise-free spec-converted accelerometer readings of one sequence (flattened)."""
    mask = jnp.ones(u_gyr.shape[:1], dtype=u_gyr.dtype)
    return predict_acc_readings(theta, delta, f0, u_gyr, mask, dt, kind).reshape(-1)


def sequence_fisher(
    theta: Float[Array, "P"],
    f0: Float[Array, "3"],
    u_gyr: Float[Array, "N 3"],
    dt: float | Float[Array, ""],
    sigma_acc: float | Float[Array, ""],
    sigma_gyr: float | Float[Array, ""],
    kind: str,
) -> Float[Array, "P P"]:
    """Marginal (start direction removed) Fisher information of one sequence on ``theta``.

    ``sigma_acc``, ``sigma_gyr``: per-component noise std of the spec-converted readings (g,
    rad/s), rounding included. ``sigma_gyr = 0`` drops the errors-in-variables term.
    """
    p = theta.shape[0]
    delta = jnp.zeros(2, theta.dtype)
    h = lambda z: predicted_acc(z[:p], z[p:], f0, u_gyr, dt, kind)  # noqa: E731
    j = jax.jacfwd(h)(jnp.concatenate([theta, delta]))
    j_g = jax.jacfwd(lambda ug: predicted_acc(theta, delta, f0, ug, dt, kind))(u_gyr).reshape(j.shape[0], -1)
    cov = sigma_acc**2 * jnp.eye(j.shape[0], dtype=j.dtype) + sigma_gyr**2 * (j_g @ j_g.T)
    return schur_marginal(gaussian_fisher(j, cov), p)


def protocol_fisher(
    theta: Float[Array, "P"],
    f0s: Float[Array, "M 3"],
    u_gyr: Float[Array, "M N 3"],
    dt: float | Float[Array, ""],
    sigma_acc: float | Float[Array, ""],
    sigma_gyr: float | Float[Array, ""],
    kind: str,
    batch_size: int = 20,
) -> Float[Array, "P P"]:
    """Total information of ``M`` independent sequences (sum of :func:`sequence_fisher`).

    ``f0s``: true start directions; ``u_gyr``: noise-free spec-converted gyroscope readings.
    Sequences are processed ``batch_size`` at a time (memory ~ batch * (3N)^2 floats).
    """
    per = jax.lax.map(
        lambda a: sequence_fisher(theta, a[0], a[1], dt, sigma_acc, sigma_gyr, kind), (f0s, u_gyr), batch_size=batch_size
    )
    return jnp.sum(per, axis=0)


def expected_error(
    key: jax.Array,
    cov: Float[Array, "P P"],
    cal_fn: Callable[[Float[Array, "P"]], Float[Array, "L 3"]],
    theta: Float[Array, "P"],
    q: Float[Array, "L 3"] | None = None,
    n_draws: int = 2000,
) -> Float[Array, ""]:
    """``E mean_l |q_l + G_l dtheta|`` with ``dtheta ~ N(0, cov)`` and ``G = d cal_fn / d theta``.

    Args:
        key: PRNG key of the Monte Carlo draws.
        cov: parameter covariance (e.g. the Cramer-Rao bound ``F^{-1}``).
        cal_fn: calibrated test outputs as a function of the parameters, ``(L, 3)``.
        theta: linearisation point (the true parameters).
        q: per-sample error with the true parameters (e.g. rounding); ``None`` means 0, i.e. the
            calibration-induced error alone.
        n_draws: Monte Carlo draws.
    """
    g = jax.jacfwd(cal_fn)(theta)  # (L, 3, P)
    chol = jnp.linalg.cholesky(0.5 * (cov + cov.T))
    d = jax.random.normal(key, (n_draws, theta.shape[0]), dtype=theta.dtype) @ chol.T
    e = jnp.einsum("lkp,dp->dlk", g, d)
    if q is not None:
        e = e + q[None]
    return jnp.mean(jnp.linalg.norm(e, axis=-1))


__all__ = [
    "expected_error",
    "gaussian_fisher",
    "predicted_acc",
    "protocol_fisher",
    "schur_marginal",
    "sequence_fisher",
]
