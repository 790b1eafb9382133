"""Fisher information and Cramer-Rao bounds for the self-calibration protocol of Dataset 2.

For a Gaussian measurement model ``z = h(phi) + n``, ``n ~ N(0, Sigma)``, the Fisher information
is ``F = J^T Sigma^{-1} J`` with ``J = dh/dphi`` (:func:`gaussian_fisher`). When ``phi = (theta,
nu)`` holds nuisance parameters ``nu``, the information on ``theta`` alone is the Schur complement
``F_tt - F_tn F_nn^{-1} F_nt`` (:func:`schur_marginal`), and any unbiased estimator has
``Cov(theta_hat) >= F^{-1}`` (the Cramer-Rao bound).

The protocol (:func:`protocol_fisher`): each sequence ``m`` is measured as spec-converted
accelerometer readings ``u_a,n = K_a^{-1} (Phi_n(w_c)^T f_0,m + e_a) + n_a`` where ``w_c`` is the
calibrated gyroscope reading ``K_g u_g,n - e_g`` (the same model as :mod:`jaxcal.online`; the
calibration parameters ``theta`` use the layout of :func:`jaxcal.online.make_filter`) and the start
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

Static and traced: ``kind`` (the parameter layout) is static in :func:`protocol_fisher`, which
passes the :class:`~jaxcal.online.Filter` of that kind inward; everything else is traced.
Dimension letters: ``Q`` parameters, ``K`` residuals (or parameters plus nuisances), ``M``
sequences, ``N`` samples per sequence, ``L`` test samples.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from jaxtyping import Float

from jaxcal.arrays import Array
from jaxcal.online import Filter, make_filter

__all__ = [
    "expected_error",
    "gaussian_fisher",
    "predicted_acc",
    "protocol_fisher",
    "schur_marginal",
    "sequence_fisher",
]


def gaussian_fisher(
    jac: Float[Array, "K Q"], cov: Float[Array, "K K"] | None = None, sigma: float | Float[Array, ""] = 1.0
) -> Float[Array, "Q Q"]:
    """``J^T Sigma^{-1} J``; ``Sigma = cov`` if given, else ``sigma^2 I``.

    Args:
        jac: (K, Q) Jacobian ``J = dh/dphi`` of the noise-free measurements.
        cov: (K, K) noise covariance ``Sigma``; None: ``sigma^2 I``.
        sigma: noise std, used when ``cov`` is None.
    """
    if cov is None:
        return jac.T @ jac / sigma**2
    chol = jnp.linalg.cholesky(cov)
    w = jax.scipy.linalg.solve_triangular(chol, jac, lower=True)
    return w.T @ w


def schur_marginal(fisher: Float[Array, "K K"], p: int) -> Float[Array, "Q Q"]:
    """Information on the first ``p`` parameters with the remaining (nuisance) ones unknown.

    Args:
        fisher: (K, K) information on ``[parameters, nuisances]``.
        p: number of parameters of interest (static: it sets the shapes).
    """
    a, b, d = fisher[:p, :p], fisher[:p, p:], fisher[p:, p:]
    out = a - b @ jnp.linalg.solve(d, b.T)
    return 0.5 * (out + out.T)


def predicted_acc(
    filt: Filter,
    theta: Float[Array, " Q"],
    delta: Float[Array, "2"],
    f0: Float[Array, "3"],
    u_gyr: Float[Array, "N 3"],
    dt: float | Float[Array, ""],
) -> Float[Array, " 3*N"]:
    """Noise-free spec-converted accelerometer readings of one sequence (flattened).

    Args:
        filt: :class:`~jaxcal.online.Filter` of the parameter layout (:func:`~jaxcal.online.make_filter`).
        theta: (Q,) calibration parameters.
        delta: (2,) tangent-plane offset of the start direction (the nuisance).
        f0: (3,) start direction (g).
        u_gyr: (N, 3) spec-converted gyroscope readings (rad/s).
        dt: sample period (s).
    """
    mask = jnp.ones(u_gyr.shape[:1], dtype=u_gyr.dtype)
    return filt.predict_acc_readings(theta, delta, f0, u_gyr, mask, dt).reshape(-1)


def sequence_fisher(
    filt: Filter,
    theta: Float[Array, " Q"],
    f0: Float[Array, "3"],
    u_gyr: Float[Array, "N 3"],
    dt: float | Float[Array, ""],
    sigma_acc: float | Float[Array, ""],
    sigma_gyr: float | Float[Array, ""],
) -> Float[Array, "Q Q"]:
    """Marginal (start direction removed) Fisher information of one sequence on ``theta``.

    Args:
        filt: :class:`~jaxcal.online.Filter` of the parameter layout (:func:`~jaxcal.online.make_filter`).
        theta: (Q,) linearisation point (the true parameters).
        f0: (3,) true start direction (g).
        u_gyr: (N, 3) noise-free spec-converted gyroscope readings (rad/s).
        dt: sample period (s).
        sigma_acc, sigma_gyr: per-component noise std of the spec-converted readings (g, rad/s),
            rounding included; ``sigma_gyr = 0`` drops the errors-in-variables term.
    """
    p = theta.shape[0]
    delta = jnp.zeros(2, theta.dtype)
    h = lambda z: predicted_acc(filt, z[:p], z[p:], f0, u_gyr, dt)  # noqa: E731
    j = jax.jacfwd(h)(jnp.concatenate([theta, delta]))
    j_g = jax.jacfwd(lambda ug: predicted_acc(filt, theta, delta, f0, ug, dt))(u_gyr).reshape(j.shape[0], -1)
    cov = sigma_acc**2 * jnp.eye(j.shape[0], dtype=j.dtype) + sigma_gyr**2 * (j_g @ j_g.T)
    return schur_marginal(gaussian_fisher(j, cov), p)


def protocol_fisher(
    theta: Float[Array, " Q"],
    f0s: Float[Array, "M 3"],
    u_gyr: Float[Array, "M N 3"],
    dt: float | Float[Array, ""],
    sigma_acc: float | Float[Array, ""],
    sigma_gyr: float | Float[Array, ""],
    kind: str,
    batch_size: int = 20,
) -> Float[Array, "Q Q"]:
    """Total information of ``M`` independent sequences (sum of :func:`sequence_fisher`).

    Call under ``jit`` with ``kind`` and ``batch_size`` static.

    Args:
        theta: linearisation point (the true parameters, :func:`jaxcal.online.make_filter` layout).
        f0s: true start directions of the sequences.
        u_gyr: noise-free spec-converted gyroscope readings.
        dt: sample period (s).
        sigma_acc, sigma_gyr: per-component noise std of the spec-converted readings (g, rad/s),
            rounding included; ``sigma_gyr = 0`` drops the errors-in-variables term.
        kind: (static) ``"diag"`` or ``"affine"``.
        batch_size: (static) sequences per ``lax.map`` batch (memory ~ batch * (3N)^2 floats).
    """
    filt = make_filter(kind)
    per = jax.lax.map(
        lambda a: sequence_fisher(filt, theta, a[0], a[1], dt, sigma_acc, sigma_gyr), (f0s, u_gyr), batch_size=batch_size
    )
    return jnp.sum(per, axis=0)


def expected_error(
    key: jax.Array,
    cov: Float[Array, "Q Q"],
    cal_fn: Callable[[Float[Array, " Q"]], Float[Array, "L 3"]],
    theta: Float[Array, " Q"],
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

