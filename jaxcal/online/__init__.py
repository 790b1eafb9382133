"""jaxcal's streaming self-calibration: an iterated information filter on exact consistency residuals.

The thesis (chapter 4) calibrates an accelerometer and a gyroscope against each other, one
sequence at a time, with two small neural networks. This module does the same job with a
*parametric* model estimated by maximum likelihood in streaming form, and reaches the
quantisation floor of Dataset 2.

Model. Raw counts are first spec-converted (eq. 4.8), ``u = (y - b_spec) / s_spec``; the
calibration is linear in ``u``::

    a_c = K_a u_a - e_a        (g)        w_c = K_g u_g - e_g        (rad/s)

with ``K = I + D``. ``kind="diag"``: ``D`` diagonal (thesis eq. 4.6 truth, 6 + 6 parameters);
``kind="affine"``: ``D_a`` upper triangular (6) and ``D_g`` full (9), 9 + 12 parameters. A rotation
applied to both sensor frames leaves every self-consistency residual unchanged, so a full affine
model has a 3-dimensional gauge freedom; restricting the accelerometer matrix to upper-triangular
fixes it (as in Tedaldi et al. 2014).

Measurement model of one sequence (body rotating about the sensor's centre, CONVENTIONS.md):
every accelerometer sample is gravity seen from the body, ``f_n = Phi_n(w_c)^T f_0`` with
``f_{n+1} = Exp(w_c,n dt)^T f_n`` (:func:`jaxcal.rotation.propagate_specific_force`) and an
unknown start direction ``f_0`` on the unit sphere (a 2-dof nuisance). The residuals
``r_n = u_a,n - K_a^{-1} (f_n + e_a)`` (all ``N`` samples, 3 components; formed in measurement
space, where the noise is) contain the thesis's two constraints as
special cases: unit norm of the static ends (eq. 4.13, L2) and gravity carried by the calibrated
gyroscope from the first to the last sample (eq. 4.11-4.12), and add every intermediate sample.
No static-gyro residual is used: at the static ends the raw gyro reads ``round(b)`` exactly, so
those samples carry a bias of up to 0.5 LSB that does not average out.

Estimator. The state is ``(theta, Lambda)``: the current estimate and its information matrix
(length ``n_params`` and ``n_params x n_params``; fixed size, independent of the number of sequences). For each new sequence:
(1) prediction: exponential forgetting ``Lambda <- lambda Lambda`` and additive process noise
``Q`` (covariance), computed as ``(I + lambda Lambda Q)^{-1} lambda Lambda`` so that ``Q = 0``
is exact; (2) a few Gauss-Newton iterations on ``|r(theta, f_0)|^2 / sigma^2 + |theta -
theta_prior|^2_Lambda`` (jointly in ``theta`` and the 2-dof ``f_0`` perturbation; Jacobians with
``jax.jacfwd``); (3) marginalisation of ``f_0`` by the Schur complement, which gives the new
``Lambda``. This is an iterated extended information filter (MAP relinearised per sequence). The
whole pass is one ``jax.lax.scan`` inside one ``jit``; hyperparameters are a NamedTuple of
(traceable) arrays, so passes ``vmap`` over them. Use float64 (the public entry points switch it
on locally): the rounding floor is 1e-5 relative.

Static and traced. The parameter layout (``kind``) is the only static choice: :func:`make_filter`
closes over it once and returns a :class:`Filter` (``init``, ``predict``, ``update``, ``unpack``,
``calibrate_acc`` ...), optax-style, so the functions inside take no ``kind``. The entry points
(:func:`online_scan`, :func:`online_pass`, :func:`online_nn_scan`, :func:`to_linear_cal`,
:func:`fit_online_recording`) take ``kind`` as a static argument (a new kind compiles anew);
:class:`OnlineHP`, :class:`NNOnlineHP`, states and data are traced (vmappable, no recompile).
:class:`Calib` is the filter's internal, spec-relative parameterisation; the interchange type is
:class:`~jaxcal.sensor.LinearCal` (:func:`to_linear_cal`).

Dimension letters: ``Q`` parameters (``n_params``), ``M`` sequences, ``N`` samples per sequence,
``L`` samples of a recording, ``B`` sequences in the replay buffer.
"""

from jaxcal.online.filter import (
    HOLD,
    KINDS,
    PROPAGATE_UNROLL,
    Calib,
    Filter,
    OnlineHP,
    OnlineState,
    diag_theta,
    make_filter,
    tangent_basis,
    to_linear_cal,
)
from jaxcal.online.nn import (
    NNOnlineHP,
    NNState,
    ZeroLastMLP,
    nn_calibrate,
    nn_calibrate_acc,
    nn_calibrate_gyr,
    online_nn_scan,
    online_nn_scan_jit,
    thesis_acc_loss,
    thesis_gyro_loss,
)
from jaxcal.online.passes import (
    SequenceBatch,
    fit_online_recording,
    online_pass,
    online_scan,
    online_scan_jit,
    spec_sequences,
)

__all__ = [
    "KINDS",
    "PROPAGATE_UNROLL",
    "Calib",
    "Filter",
    "HOLD",
    "NNOnlineHP",
    "NNState",
    "OnlineHP",
    "OnlineState",
    "SequenceBatch",
    "ZeroLastMLP",
    "fit_online_recording",
    "make_filter",
    "diag_theta",
    "nn_calibrate",
    "nn_calibrate_acc",
    "nn_calibrate_gyr",
    "online_nn_scan",
    "online_nn_scan_jit",
    "online_pass",
    "online_scan",
    "online_scan_jit",
    "spec_sequences",
    "tangent_basis",
    "thesis_acc_loss",
    "thesis_gyro_loss",
    "to_linear_cal",
]
