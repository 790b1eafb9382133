"""The multipos fit on prepared data: accelerometer, then gyroscope (pure, vmappable over weights).

:func:`fit_prepared` is the pure JAX fit (``config`` static, everything else traced);
:data:`fit_prepared_jit` its jitted form; :func:`fit_prepared_numpy` runs it in float64 on numpy
data; :func:`fit_multipos` prepares a recording's arrays first.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Float

from jaxcal.arrays import Array
from jaxcal.multipos.acc import acc_norm_errors, fit_acc, fit_acc_determined
from jaxcal.multipos.data import KnownRotations, MultiposData, VerticalTurns, calibrated_acc_sums, prepare
from jaxcal.multipos.gyro import GyroArgs, gyr_residuals, rest_gsens, turn_init
from jaxcal.precision import float64
from jaxcal.sensor import LinearCal

__all__ = [
    "MultiposConfig",
    "MultiposFit",
    "fit_prepared",
    "fit_prepared_jit",
    "fit_prepared_numpy",
    "fit_multipos",
]


class MultiposConfig(NamedTuple):
    """Options of the multipos fit. Static: every field is a Python value, and
    :data:`fit_prepared_jit` takes the config as a static argument (a new config recompiles).

    Args:
        acc_model: ``"9"`` or ``"12"``.
        gyro_bias: ``"static"`` (mean over the static intervals in use) or ``"init"`` (the first
            interval only, as imu_tk).
        g_sensitivity: also fit the gyro g-sensitivity ``G_s`` ((rad/s)/g); needs ``gyro_bias``
            ``"static"``: bias and ``G_s`` come from the rests jointly (:func:`rest_gsens`).
        gsens_from: with ``g_sensitivity``, ``"rests"`` (default: ``G_s = G H`` with ``H`` from the
            rests' regression, held fixed in the gyro fit; trace included) or ``"transitions"``
            (``G_s`` fitted from the carried gravity, an independent estimate whose trace the
            transitions do not determine; bias still from the rests' regression).
        earth_rate_up: the vertical component of the Earth's rate at the rig, rad/s
            (``EARTH_RATE sin(latitude)``): at rest the gyro reads it along the specific force, so the
            rests' ``G_s`` holds it as ``earth_rate_up I`` per g; it is taken out of the reported
            ``G_s`` (0: left in, at most 0.0042 (deg/s)/g).
        midpoint: midpoint rates (else the left sample, zero-order hold).
        max_steps: LM iteration cap.
        prior: optional :class:`~jaxcal.multipos.acc.DatasheetPrior` (MAP on scales and
            cross-axis terms; ``None``, the default, uses the data alone).
        acc_ridge: weak ridge on the accelerometer's cross-axis terms (see :func:`fit_acc`; 0 turns
            it off).
        acc_fit: ``"full"`` (:func:`fit_acc`) or ``"determined"`` (:func:`fit_acc_determined`: move
            the recording's own units only along the combinations the poses determine; 9-parameter
            model).
        gyr_fit: ``"full"`` or ``"none"`` (the gyroscope stays as recorded: ``G = I``, ``b = 0``).
    """

    acc_model: str = "9"
    gyro_bias: str = "static"
    g_sensitivity: bool = False
    midpoint: bool = True
    max_steps: int = 100
    prior: Any = None
    acc_ridge: float = 1e-2
    acc_fit: str = "full"
    gyr_fit: str = "full"
    gsens_from: str = "rests"
    earth_rate_up: float = 0.0


class MultiposFit(NamedTuple):
    """Result: ``acc``/``gyr`` calibrations (applied direction, :class:`~jaxcal.sensor.LinearCal`),
    ``gsens`` (3, 3) ((rad/s)/g, zero unless fitted), and the final residual norms of the two
    least-squares problems."""

    acc: LinearCal
    gyr: LinearCal
    gsens: Float[Array, "3 3"]
    acc_cost: Float[Array, ""]
    gyr_cost: Float[Array, ""]


def _data_cost(args: GyroArgs, s: Float[Array, ""], theta: Float[Array, " Q"]) -> Float[Array, ""]:
    """The gyro fit's cost at scale ``s`` and ``theta``: its data rows alone (no prior)."""
    return jnp.sum(gyr_residuals(theta, args._replace(scale=s)) ** 2)


def _scale_start(args: GyroArgs, zero: Float[Array, " Q"]) -> tuple[Float[Array, ""], Float[Array, " S"]]:
    """The gyro fit's scalar start ``s0`` (``G = s I``): the point of least cost on a grid over both
    signs, 4 per decade, and the grid's costs (the data rows alone, no prior).

    Known closed rotations are left out of the cost that picks ``s0`` wherever transitions are fitted:
    any whole number of revolutions closes a turn, so their rows have a minimum at every count and the
    coarse grid can land on a wrong one (a noise-free Ferraris fold chose ten revolutions). With no
    transition (the turns alone), the known rows pick it. The returned costs include every row."""
    grid = jnp.concatenate([jnp.logspace(-7, 1, 33), -jnp.logspace(-7, 1, 33)]).astype(zero.dtype)

    def costs(a: GyroArgs) -> Float[Array, " S"]:
        return jnp.nan_to_num(jax.vmap(lambda s: _data_cost(a, s, zero))(grid), nan=jnp.inf)

    c = costs(args)
    if args.known is None:
        return grid[jnp.argmin(c)], c
    free = grid[jnp.argmin(costs(args._replace(known=None)))]
    return jnp.where(jnp.sum(args.w) > 0, free, grid[jnp.argmin(c)]), c


def fit_prepared(
    data: MultiposData,
    config: MultiposConfig = MultiposConfig(),
    *,
    acc_w: Float[Array, " P"] | None = None,
    gyr_w: Float[Array, " J"] | None = None,
    known: KnownRotations | None = None,
    known_w: Float[Array, " K"] | None = None,
    turns: VerticalTurns | None = None,
    turns_w: Float[Array, " T"] | None = None,
) -> MultiposFit:
    """Accelerometer then gyroscope fit on prepared data (pure; vmappable over the weights).

    ``acc_w`` (per pose) and ``gyr_w`` (per transition) default to ones; a zero leaves that pose
    or transition out (leave-poses-out folds). Unusable transitions (``seg_ok``) are always left
    out. ``known`` (optional, :func:`prepare_known`): sections of known rotation, each adding the
    3 rows ``log_so3(R_known^T R_int)`` to the gyro fit (weights ``known_w``, default ones); they
    observe what gravity carrying cannot, e.g. the scale about a vertical turning axis.
    ``turns`` (optional, :func:`prepare_turns`): whole turns about the vertical, unlabelled, each
    adding the 3 rows of :func:`vertical_turn_residuals` (weights ``turns_w``); with at least three
    turns the gyro fit also starts from :func:`turn_init` when that beats the scalar grid start.
    ``config.prior``: optional datasheet prior (MAP). Call under ``jax.enable_x64(True)`` for raw
    counts (as :func:`fit_multipos` does).

    Args:
        data: prepared poses and transitions (:func:`prepare`).
        config: :class:`MultiposConfig` (static).
        acc_w: (P,) weight per pose (default ones).
        gyr_w: (J,) weight per transition (default ones).
        known: optional :class:`KnownRotations`.
        known_w: (K,) weights of the known rotations (default ones).
        turns: optional :class:`VerticalTurns`.
        turns_w: (T,) weights of the turns (default ones).
    """
    P = data.pose_acc.shape[0]
    dtype = data.pose_acc.dtype
    if config.acc_fit not in ("full", "determined") or config.gyr_fit not in ("full", "none"):
        raise ValueError(f"acc_fit must be 'full' or 'determined' and gyr_fit 'full' or 'none', got "
                         f"{config.acc_fit!r} and {config.gyr_fit!r}")
    if config.g_sensitivity and (config.gyro_bias != "static" or config.gsens_from not in ("rests", "transitions")):
        raise ValueError(f"g_sensitivity takes the bias from all rests (gyro_bias 'static', got {config.gyro_bias!r}) and "
                         f"gsens_from 'rests' or 'transitions' (got {config.gsens_from!r})")
    acc_w = jnp.ones(P, dtype) if acc_w is None else acc_w
    gyr_w = jnp.ones(P - 1, dtype) if gyr_w is None else gyr_w
    gyr_w = gyr_w * data.seg_ok.astype(dtype)
    if config.acc_fit == "determined":
        acc, _ = fit_acc_determined(data.pose_acc, acc_w)
        acc_cost = jnp.sum(acc_w * acc_norm_errors(acc, data.pose_acc) ** 2)
    else:
        acc, acc_cost = fit_acc(data.pose_acc, acc_w, config.acc_model, config.max_steps, config.prior, config.acc_ridge)
    if config.gyr_fit == "none":
        zero = jnp.zeros((3, 3), dtype)
        return MultiposFit(acc, LinearCal(jnp.eye(3, dtype=dtype), jnp.zeros(3, dtype)), zero, acc_cost, jnp.asarray(0.0, dtype))
    f = (data.pose_acc - acc.b) @ acc.A.T
    u = f / jnp.linalg.norm(f, axis=-1, keepdims=True)
    # gyro bias from the static intervals (of the poses in use); with g-sensitivity, jointly with it
    wn = acc_w * data.pose_n
    h = None
    if config.g_sensitivity:
        bg, h = rest_gsens(data.pose_gyr, f, wn)
    elif config.gyro_bias == "init":
        bg = data.pose_gyr[0]
    else:
        bg = jnp.sum(wn[:, None] * data.pose_gyr, 0) / jnp.sum(wn)
    fit_gs = config.g_sensitivity and config.gsens_from == "transitions"
    # the scale (1 here) is set per grid point below, then to the best one
    args = GyroArgs(data, bg, jnp.asarray(1.0, dtype), fit_gs, calibrated_acc_sums(acc, data), u, gyr_w,
                    rest_gsens=None if fit_gs else h)
    if known is not None:
        known_w = jnp.ones(known.R.shape[0], dtype) if known_w is None else known_w
        args = args._replace(known=known, known_w=known_w, known_fsum=calibrated_acc_sums(acc, known))
    if turns is not None:
        turns_w = jnp.ones(turns.angle.shape[0], dtype) if turns_w is None else turns_w
        args = args._replace(turns=turns, turns_w=turns_w, acc=acc)
    zero = jnp.zeros(18 if fit_gs else 9, dtype)
    s0, costs = _scale_start(args, zero)
    theta0 = zero
    if turns is not None and turns.angle.shape[0] >= 3:  # label-free Ferraris start, if it is better
        gc = turn_init(bg, acc, turns, turns_w * turns.seg_ok.astype(dtype), jnp.sign(s0))
        th_c = zero.at[:9].set((gc / s0 - jnp.eye(3, dtype=dtype)).ravel())
        c_c = jnp.nan_to_num(_data_cost(args, s0, th_c), nan=jnp.inf)
        theta0 = jnp.where(c_c < jnp.min(costs), th_c, zero)
    args = args._replace(scale=s0, prior=config.prior)
    solver = optx.LevenbergMarquardt(rtol=1e-9, atol=1e-12)
    sol = optx.least_squares(gyr_residuals, solver, theta0, args=args, max_steps=config.max_steps, throw=False)
    g = s0 * (jnp.eye(3, dtype=dtype) + sol.value[:9].reshape(3, 3))
    if fit_gs:
        gs = sol.value[9:18].reshape(3, 3)
    else:
        gs = jnp.zeros((3, 3), dtype) if h is None else g @ h - config.earth_rate_up * jnp.eye(3, dtype=dtype)
    gyr_cost = jnp.sum(gyr_residuals(sol.value, args._replace(prior=None)) ** 2)
    return MultiposFit(acc, LinearCal(g, bg), gs, acc_cost, gyr_cost)


#: XLA options of :data:`fit_prepared_jit`. One multipos fit is compile-bound: on the Xsens session
#: (40 poses) it compiled in 2.78 s and ran in 182 ms; without the backend's optimisation passes it
#: compiles in 1.73 s and runs in 294 ms (0.94 s saved per compile; largest difference in the result
#: 2.1e-8, in raw counts; medians of 3, ``python -m benchmarks.multipos_compile``). A fold loop runs
#: the fit many times and keeps the passes (:func:`jaxcal.multipos.heldout.fold_scores`: 40 folds,
#: 3.1 s compile + 3.9 s against 1.9 s + 12.7 s).
FIT_COMPILER_OPTIONS = {"xla_backend_optimization_level": 0}

#: :func:`fit_prepared` jitted, ``config`` static: ``fit_prepared_jit(data, config, acc_w=..., ...)``
#: (compiled with :data:`FIT_COMPILER_OPTIONS`).
fit_prepared_jit = jax.jit(fit_prepared, static_argnames=("config",), compiler_options=FIT_COMPILER_OPTIONS)


def fit_multipos(
    t: np.ndarray,
    acc: np.ndarray,
    gyr: np.ndarray,
    intervals: np.ndarray,
    config: MultiposConfig = MultiposConfig(),
    *,
    gyr_limit: float | None = None,
    block: int = 8,
    turns: VerticalTurns | None = None,
) -> MultiposFit:
    """:func:`prepare` + :func:`fit_prepared` in float64 (optional vertical ``turns``, see
    :func:`prepare_turns`); returns numpy-backed arrays.

    Args:
        t: (N,) times (s).
        acc, gyr: (N, 3) outputs (raw counts or physical units).
        intervals: (P, 2) static ``[start, stop)`` sample indices, in time order.
        config: :class:`MultiposConfig`.
        gyr_limit: saturation limit (a transition reaching it is left out), or ``None``.
        block: samples per integration block (:func:`prepare`).
        turns: optional :class:`VerticalTurns`.
    """
    data = prepare(t, acc, gyr, intervals, gyr_limit=gyr_limit, midpoint=config.midpoint, block=block)
    return fit_prepared_numpy(data, config, turns=turns)


@float64
def fit_prepared_numpy(data: MultiposData, config: MultiposConfig = MultiposConfig(), *,
                       turns: VerticalTurns | None = None) -> MultiposFit:
    """:data:`fit_prepared_jit` in float64 on numpy-prepared data (and optional vertical ``turns``);
    numpy-backed result.

    Args:
        data: prepared poses and transitions (numpy, :func:`prepare`).
        config: :class:`MultiposConfig` (static: a new config recompiles).
        turns: optional :class:`VerticalTurns` (numpy).
    """
    d = jax.tree_util.tree_map(jnp.asarray, data)
    tv = None if turns is None else jax.tree_util.tree_map(jnp.asarray, turns)
    P = d.pose_acc.shape[0]
    # the weights passed as arrays, as the field path and the scores pass theirs: one compiled fit for all
    fit = fit_prepared_jit(d, config, acc_w=jnp.ones(P, d.pose_acc.dtype), gyr_w=jnp.ones(P - 1, d.pose_acc.dtype), turns=tv)
    return jax.tree_util.tree_map(np.asarray, fit)
