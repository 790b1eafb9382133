"""Band-limited retiming of a sampled signal: a shift (``x(t - tau)``, :func:`shift_signal`) and a
stretch about the middle time (``x(t + sigma tc)``, :func:`stretch_signal`), each differentiable in its
parameter. The vocabulary's ``time_offset`` and ``clock_skew`` steps (:mod:`jaxcal.diagnose.vocabulary`)
and the model chain of :mod:`jaxcal.diagnose.effects` use them.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero
from jaxtyping import Float

from jaxcal.arrays import Array

__all__ = ["shift_signal", "stretch_signal"]


def shift_signal(x: Float[Array, "N C"], tau: Float[Array, ""], dt: float | Float[Array, ""]) -> Float[Array, "N C"]:
    """``x(t - tau)`` by a band-limited (Fourier) shift of the even extension of ``x``.

    Differentiable in ``tau`` at every value (sub-sample and many-sample shifts alike); the even
    extension avoids the wrap-around jump of a plain circular shift. The first/last ``|tau|/dt``
    samples are extrapolated by reflection, so fits should drop them.

    Args:
        x: (N, C) signal.
        tau: shift (s; positive delays).
        dt: sample interval (s).
    """
    n = x.shape[0]
    xe = jnp.concatenate([x, x[::-1]], axis=0)
    spec = jnp.fft.rfft(xe, axis=0)
    freq = jnp.fft.rfftfreq(2 * n, d=dt)
    phase = jnp.exp(-2j * jnp.pi * freq * tau)
    return jnp.fft.irfft(spec * phase[:, None], n=2 * n, axis=0)[:n].astype(x.dtype)


def _chirp(j2: np.ndarray, m: int, sigma, x_dtype) -> Array:
    """``exp(i pi (1 + sigma) j2 / m)`` for integers ``j2``: the ``sigma = 0`` phase reduced modulo
    ``2 pi`` in exact integer arithmetic (numpy, static), so the traced part stays small (float32 too)."""
    cdtype = jnp.result_type(x_dtype, jnp.complex64)
    base = jnp.asarray(np.exp(1j * np.pi * (j2 % (2 * m)) / m), cdtype)
    return base * jnp.exp(1j * jnp.pi * sigma * jnp.asarray(j2 / m, x_dtype)).astype(cdtype)


def _stretch(x: Float[Array, "N C"], sigma: Float[Array, ""], c: Float[Array, ""], order: int = 0) -> Float[Array, "N C"]:
    """The band-limited interpolant of ``x``'s even extension (period ``m = 2 N`` samples), or its
    ``order``-th derivative per sample, at the fractional sample positions ``u_n = c + (1 + sigma) (n - c)``:
    ``sum_k w_k X_k (2 pi i k / m)^order e^(2 pi i k u_n / m)`` over the one-sided spectrum, with
    ``k u_n = (1 + sigma) k n - sigma k c`` and Bluestein's ``k n = (k^2 + n^2 - (n - k)^2) / 2`` (a chirp
    z-transform: one convolution by FFT)."""
    n = x.shape[0]
    m = 2 * n
    spec = jnp.fft.rfft(jnp.concatenate([x, x[::-1]], axis=0), axis=0)  # k = 0..n
    k = np.arange(n + 1, dtype=np.int64)
    wk = np.where((k == 0) | (k == n), 1.0, 2.0) * (2j * np.pi * k / m) ** order
    a = spec * (jnp.asarray(wk) * jnp.exp(-2j * jnp.pi * sigma * c * jnp.asarray(k / m, x.dtype)) * _chirp(k**2, m, sigma, x.dtype))[:, None]
    size = 1 << int(np.ceil(np.log2(2 * n + 1)))  # lags n - k in [-n, n - 1] do not wrap
    j = np.arange(size, dtype=np.int64)
    lag = np.where(j < n, j, j - size)
    h = jnp.conj(_chirp(lag**2, m, sigma, x.dtype))
    conv = jnp.fft.ifft(jnp.fft.fft(a.astype(h.dtype), size, axis=0) * jnp.fft.fft(h)[:, None], axis=0)[:n]
    out = jnp.real(conv * _chirp(np.arange(n, dtype=np.int64) ** 2, m, sigma, x.dtype)[:, None]) / m
    return out.astype(x.dtype)


def _per_sample_derivative(x: Float[Array, "N C"]) -> Float[Array, "N C"]:
    """``dx/dn`` (per sample) of the band-limited interpolant of ``x``'s even extension."""
    n = x.shape[0]
    spec = jnp.fft.rfft(jnp.concatenate([x, x[::-1]], axis=0), axis=0)
    k = np.arange(n + 1)
    ik = 2j * np.pi * k / (2 * n) * (k < n)
    return jnp.fft.irfft(spec * ik[:, None], n=2 * n, axis=0)[:n].astype(x.dtype)


@partial(jax.custom_jvp, nondiff_argnums=(3,))
def _stretch_jvp(x, sigma, c, order=0):
    return _stretch(x, sigma, c, order)


@partial(_stretch_jvp.defjvp, symbolic_zeros=True)
def _stretch_tangent(order, primals, tangents):
    """The tangent in ``sigma`` from the primal alone, ``(n - c)`` times the next derivative of the
    interpolant at ``u_n`` (computed once, however many tangents a Jacobian pushes), plus the
    stretch of a tangent of ``x`` when there is one; through this rule again for higher orders."""
    x, sigma, c = primals
    xd, sd, _ = tangents
    y = _stretch_jvp(x, sigma, c, order)
    out = jnp.zeros_like(y) if isinstance(xd, SymbolicZero) else _stretch_jvp(xd, sigma, c, order)
    if not isinstance(sd, SymbolicZero):
        pos = (jnp.arange(x.shape[0]) - c).astype(x.dtype)[:, None]
        out = out + pos * _stretch_jvp(x, sigma, c, order + 1) * sd
    return y, out


def stretch_signal(x: Float[Array, "N C"], sigma: float | Float[Array, ""], tc: Float[Array, " N"], dt: float | Float[Array, ""]) -> Float[Array, "N C"]:
    """``x(t + sigma (t - t_mid))`` (a clock running ``1 + sigma`` times as fast, about the middle
    time ``t_mid`` where ``tc = t - t_mid`` is 0) by band-limited interpolation of the even extension of
    ``x`` (a chirp z-transform; cost a few FFTs of twice the length).

    ``sigma = 0`` returns ``x`` itself (the first-order form ``x + sigma tc dx/dt``, whose derivative
    in ``sigma`` is the exact one there), so the regressors at zero cost one FFT pair; the tangent in
    ``sigma`` is formed once from the primal (:func:`_stretch_tangent`). Like :func:`shift_signal`,
    the first/last ``|sigma tc| / dt`` samples are reflections.

    Args:
        x: (N, C) signal on a uniform grid.
        sigma: relative clock rate (dimensionless; 1e-6 per ppm).
        tc: (N,) times from the middle (s).
        dt: sample interval (s).
    """
    c = -tc[0] / dt  # the middle, in samples

    def first_order(x):
        return x + sigma * (jnp.arange(x.shape[0]) - c).astype(x.dtype)[:, None] * _per_sample_derivative(x)

    return jax.lax.cond(sigma == 0.0, first_order, lambda x: _stretch_jvp(x, sigma, c), x)
