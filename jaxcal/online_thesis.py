"""The thesis's online adaptive calibration (Claesson & Marklund 2019, sections 4.3-4.6), as published.

Two 3-5-10-5-3 leaky-ReLU(0.1) networks map normalised raw counts (eq. 3.7) to physical units:
``NN_a`` (accelerometer, g) and ``NN_phi`` (gyroscope, rad/s). The algorithm:

1. **Initial training** (4.3): every tenth training sequence, targets = spec conversion (eq. 4.8),
   full-batch Adam on the MSE for ``init_epochs`` epochs, each network separately.
2. **Adaptive loop** (4.4-4.5), one ``jax.lax.scan`` step per training sequence ``m``:

   a. *gyroscope update* (eq. 4.9-4.10): with ``a_c,n = NN_a(a_n)`` held fixed (``stop_gradient``)
      and ``phi_c,n = NN_phi(phi_n)``, ``a_phi,n+1 = R(phi_c,n, dt)^T a_c,n`` and the loss is
      ``MSE(a_c,n+1, a_phi,n+1)`` over ``n = 1..N-1``; ``gyr_steps`` full-sequence Adam steps.
   b. *accelerometer update* (eq. 4.11-4.13): with ``NN_phi`` fixed,
      ``R_tot = R_1 R_2 ... R_{N-1}``, ``a_phi,N = R_tot^T a_c,1`` (a fixed target,
      ``stop_gradient``: the thesis gives ``a_phi,N`` to ``NN_a`` "as target") and the loss is
      ``w MSE(a_phi,N, a_c,N) + (1 - w) |1 - |a_c,N||``; ``acc_steps`` Adam steps.
   c. *evaluation* (eq. 4.14): ``e_g`` and ``e_a`` on the validation sequences, every iteration.

**Rotation convention.** Eq. 4.9 and 4.12 as printed apply ``R_n`` (``a_phi,n+1 = R_n a_c,n``).
jaxcal uses the physical convention of ``CONVENTIONS.md`` -- the body-frame specific force obeys
``f_{n+1} = Exp(w_n dt)^T f_n`` -- so here ``a_phi,n+1 = R_n^T a_c,n`` and
``a_phi,N = R_tot^T a_c,1``; :func:`gyro_loss` and :func:`acc_loss` take
``convention="printed"`` to evaluate the thesis's sign (which is consistent only with data simulated
by the printed eq. 4.5). ``R_tot`` multiplies the ``N - 1`` rotations that carry sample 1 to
sample ``N`` (eq. 4.11 prints ``N`` factors; the last rate of a sequence is static, ~0).

**Choices the thesis leaves open** (all fields of :class:`OnlineThesisHParams`, traced, so whole
trainings ``vmap`` over them): learning rates, numbers of Adam steps per sequence, initial-training
epochs, initial weight scale, PRNG key. The Adam moments of each network persist from one sequence
to the next (as with repeated Keras ``fit`` calls on one compiled model); the initial training uses
its own Adam state. Every update step uses the whole sequence (one batch).

The whole algorithm, initial training included, is one ``jit``: :func:`run_online_thesis` for a
:class:`~jaxcal.sequences.Dataset2` (with validation errors; simulated by
:func:`jaxcal.simulate.dataset2`) and :func:`fit_online_thesis_recording` for a recording split
into sequences (no labels).

The per-sequence losses :func:`gyro_loss` (eq. 4.10) and :func:`acc_loss` (eq. 4.13) are the only
implementation of the thesis's losses in jaxcal; :mod:`jaxcal.online`'s NN variant averages them
over its replay buffer with ``vmap``.

Dimension letters: ``M`` sequences, ``N`` samples per sequence, ``L`` samples of a recording or
test set.
"""

from __future__ import annotations

from functools import partial
from typing import Any, Literal, NamedTuple

import jax
import jax.numpy as jnp
import optax
from jaxtyping import Float, Int, Real

from jaxcal.arrays import Array
from jaxcal.constants import ACC_RANGE_G, GYR_RANGE_RADS
from jaxcal.metrics import euclidean_error, mse, sequence_acc_error, sequence_gyro_error
from jaxcal.nn import MLP, THESIS_LEAKY_SLOPE, THESIS_ONLINE_WIDTHS, init_mlp
from jaxcal.normalise import Bounds, bounds_from_spec, normalise
from jaxcal.rotation import compose, rotation_from_rate
from jaxcal.sensor import Diag, spec_convert
from jaxcal.sequences import Dataset2, Sequences, split_equal

__all__ = [
    "INIT_EVERY",
    "ONLINE_MLP",
    "InitialTraining",
    "OnlineThesisHParams",
    "OnlineThesisResult",
    "acc_bounds",
    "acc_loss",
    "adam_steps",
    "calibrate_acc",
    "calibrate_gyr",
    "default_hparams",
    "fit_online_thesis_recording",
    "gyr_bounds",
    "gyro_loss",
    "init_params",
    "initial_training",
    "run_dataset",
    "run_from_initial",
    "run_online_thesis",
    "run_sequences",
    "stack_hparams",
    "test_set_errors",
]

Params = Any
Convention = Literal["physical", "printed"]

#: The network of Fig. 4.5: 3-5-10-5-3, leaky ReLU with slope 0.1.
ONLINE_MLP = MLP(widths=THESIS_ONLINE_WIDTHS, out_dim=3, slope=THESIS_LEAKY_SLOPE)
#: Every tenth training sequence is used for the initial training (section 4.6.1).
INIT_EVERY = 10


class OnlineThesisHParams(NamedTuple):
    """Hyperparameters of the adaptive algorithm; every field may be a traced (vmapped) array.

    The thesis states none of these values except ``w``; the defaults were chosen by vmapped
    sweeps on Dataset 2 seeds 0-3 (learning rates 1e-5..1e-3, 1/5/20 steps per sequence,
    initial-training learning rate and epochs, initial weight scale 0.3/1/3): larger online
    learning rates make the single-sample accelerometer update diverge and the gyroscope error
    fluctuate; a smaller initial scale of ``NN_a`` lowers the final accelerometer error, while
    the gyroscope does best with the default scale. ``experiments/online.py`` reports the
    sensitivity on held-out seeds.

    Attributes:
        key: PRNG key for the initial weights of both networks.
        init_lr: Adam step size of the initial training (4.3).
        init_epochs: full-batch epochs of the initial training.
        gyr_lr: Adam step size of the gyroscope updates (4.4).
        gyr_steps: Adam steps per sequence for ``NN_phi``.
        acc_lr: Adam step size of the accelerometer updates (4.5).
        acc_steps: Adam steps per sequence for ``NN_a``.
        w: weight of the rotation term in eq. 4.13 (thesis: 0.9).
        acc_init_scale, gyr_init_scale: multipliers on the initial (flax LeCun-normal) weights of
            ``NN_a`` and ``NN_phi``.
    """

    key: jax.Array
    init_lr: float | Float[Array, ""] = 3e-3
    init_epochs: int | Int[Array, ""] = 5000
    gyr_lr: float | Float[Array, ""] = 1e-4
    gyr_steps: int | Int[Array, ""] = 1
    acc_lr: float | Float[Array, ""] = 3e-5
    acc_steps: int | Int[Array, ""] = 1
    w: float | Float[Array, ""] = 0.9
    acc_init_scale: float | Float[Array, ""] = 0.3
    gyr_init_scale: float | Float[Array, ""] = 1.0


class OnlineThesisResult(NamedTuple):
    """Outcome of the adaptive algorithm.

    Attributes:
        acc_params, gyr_params: final ``NN_a`` / ``NN_phi`` parameters.
        acc_params0, gyr_params0: the parameters after the initial training.
        init_loss_acc, init_loss_gyr: final initial-training MSE (g^2, (rad/s)^2).
        gyr_loss, acc_loss: ``(M,)`` eq. 4.10 / eq. 4.13 loss of each sequence after its update.
        e_g, e_a: ``(M + 1,)`` validation errors of eq. 4.14 (rad/s, g); index 0 is after the
            initial training, ``i`` after sequence ``i``. NaN when no validation set was given.
    """

    acc_params: Params
    gyr_params: Params
    acc_params0: Params
    gyr_params0: Params
    init_loss_acc: Float[Array, ""]
    init_loss_gyr: Float[Array, ""]
    gyr_loss: Float[Array, " M"]
    acc_loss: Float[Array, " M"]
    e_g: Float[Array, " M+1"]
    e_a: Float[Array, " M+1"]


def default_hparams(key: jax.Array, **overrides: Any) -> OnlineThesisHParams:
    """The hyperparameters used for the reproduction (fields as arrays, so they stack for vmap)."""
    hp = OnlineThesisHParams(key=key)._replace(**overrides)
    return jax.tree.map(jnp.asarray, hp)


def stack_hparams(hps: list[OnlineThesisHParams]) -> OnlineThesisHParams:
    """Stack hyperparameter sets along a new leading axis for ``jax.vmap``."""
    return jax.tree.map(lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *hps)


# ----------------------------------------------------------------------------- calibration maps


def acc_bounds(spec: Diag, full_range: float = ACC_RANGE_G) -> Bounds:
    """Eq. 3.6 bounds of the accelerometer input (range +-2 g by default).

    Args:
        spec: datasheet model of the accelerometer (``s`` LSB per g, ``b`` LSB).
        full_range: ``r`` of the ``+-r`` input range (g).
    """
    return bounds_from_spec(spec, full_range)


def gyr_bounds(spec: Diag, full_range: float = GYR_RANGE_RADS) -> Bounds:
    """Eq. 3.6 bounds of the gyroscope input (range +-250 deg/s, in rad/s, by default).

    Args:
        spec: datasheet model of the gyroscope (``s`` LSB per rad/s, ``b`` LSB).
        full_range: ``r`` of the ``+-r`` input range (rad/s).
    """
    return bounds_from_spec(spec, full_range)


def calibrate_acc(
    params: Params, raw: Real[Array, "... 3"], spec: Diag, full_range: float = ACC_RANGE_G
) -> Float[Array, "... 3"]:
    """``NN_a``: raw accelerometer counts (LSB) -> calibrated specific force (g).

    Args:
        params: ``NN_a`` parameters (traced).
        raw: (..., 3) raw counts (LSB).
        spec: datasheet model (eq. 3.6 bounds).
        full_range: ``r`` of the ``+-r`` input range (g).
    """
    return ONLINE_MLP.apply({"params": params}, normalise(raw, acc_bounds(spec, full_range)))


def calibrate_gyr(
    params: Params, raw: Real[Array, "... 3"], spec: Diag, full_range: float = GYR_RANGE_RADS
) -> Float[Array, "... 3"]:
    """``NN_phi``: raw gyroscope counts (LSB) -> calibrated angular rate (rad/s).

    Args:
        params: ``NN_phi`` parameters (traced).
        raw: (..., 3) raw counts (LSB).
        spec: datasheet model (eq. 3.6 bounds).
        full_range: ``r`` of the ``+-r`` input range (rad/s).
    """
    return ONLINE_MLP.apply({"params": params}, normalise(raw, gyr_bounds(spec, full_range)))


# ----------------------------------------------------------------------------- losses


def _rotate(r: Float[Array, "... 3 3"], v: Float[Array, "... 3"], convention: Convention) -> Array:
    """``R^T v`` (physical) or ``R v`` (as printed in eq. 4.9 / 4.12)."""
    if convention == "physical":
        return jnp.einsum("...ji,...j->...i", r, v)
    if convention == "printed":
        return jnp.einsum("...ij,...j->...i", r, v)
    raise ValueError(f"convention must be 'physical' or 'printed', got {convention!r}")


def gyro_loss(
    phi_c: Float[Array, "N 3"],
    a_c: Float[Array, "N 3"],
    dt: float | Float[Array, ""],
    convention: Convention = "physical",
) -> Float[Array, ""]:
    """Eq. 4.9-4.10 averaged over one sequence.

    ``a_phi,n+1 = R(phi_c,n, dt)^T a_c,n`` (physical; ``R_n a_c,n`` if ``convention="printed"``)
    and the loss is ``mean_n (1/3) |a_c,n+1 - a_phi,n+1|^2`` over ``n = 1..N-1``.

    Args:
        phi_c: calibrated angular rates of the sequence (rad/s).
        a_c: calibrated specific force of the sequence (g).
        dt: sample period (s).
        convention: rotation sign (see module docstring).
    """
    a_phi = _rotate(rotation_from_rate(phi_c[:-1], dt), a_c[:-1], convention)
    return mse(a_c[1:], a_phi)


def acc_loss(
    a_c1: Float[Array, "3"],
    a_cN: Float[Array, "3"],
    phi_c: Float[Array, "N 3"],
    dt: float | Float[Array, ""],
    w: float | Float[Array, ""] = 0.9,
    convention: Convention = "physical",
) -> Float[Array, ""]:
    """Eq. 4.11-4.13 for one sequence.

    ``R_tot = R_1 ... R_{N-1}`` from ``phi_c`` (the ``N - 1`` rotations between the static ends),
    ``a_phi,N = R_tot^T a_c,1`` (physical; ``R_tot a_c,1`` if printed) and
    ``L = w (1/3)|a_phi,N - a_c,N|^2 + (1 - w) |1 - |a_c,N||``.
    Gradients flow into every argument; :func:`run_online_thesis` stops them at ``a_c1``, ``phi_c``.

    Args:
        a_c1: (3,) calibrated specific force at the first sample (g).
        a_cN: (3,) calibrated specific force at the last sample (g).
        phi_c: (N, 3) calibrated angular rates of the sequence (rad/s).
        dt: sample period (s).
        w: weight ``w`` of eq. 4.13 (traced).
        convention: rotation sign (see module docstring; a Python string, static).
    """
    r_tot = compose(rotation_from_rate(phi_c[:-1], dt))
    a_phi = _rotate(r_tot, a_c1, convention)
    l1 = mse(a_phi, a_cN)
    l2 = jnp.abs(1.0 - jnp.sqrt(jnp.sum(a_cN**2)))
    return w * l1 + (1.0 - w) * l2


# ----------------------------------------------------------------------------- the algorithm


def adam_steps(loss_fn, params, opt_state, opt, n_steps):
    """``n_steps`` (may be traced) steps of the optax optimiser ``opt`` on ``loss_fn(params)`` in one
    ``fori_loop``: the thesis's per-sequence network update (eq. 4.10 / 4.13).

    Args:
        loss_fn: ``params -> scalar`` loss.
        params: the network's parameters (traced).
        opt_state: ``opt``'s state for ``params``.
        opt: an ``optax.GradientTransformation`` (Adam in the thesis).
        n_steps: number of steps (may be traced).

    Returns:
        ``(params, opt_state, loss_fn(params))`` after the steps.
    """

    def body(_, carry):
        p, s = carry
        g = jax.grad(loss_fn)(p)
        u, s = opt.update(g, s, p)
        return optax.apply_updates(p, u), s

    params, opt_state = jax.lax.fori_loop(0, n_steps, body, (params, opt_state))
    return params, opt_state, loss_fn(params)


def init_params(key: jax.Array, scale) -> Params:
    """Flax LeCun-normal initial weights of the Fig. 4.5 network, multiplied by ``scale``."""
    return jax.tree.map(lambda p: scale * p, init_mlp(key, ONLINE_MLP))


class InitialTraining(NamedTuple):
    """Outcome of the initial training (section 4.3), the adaptive loop's starting point.

    Attributes:
        acc_params, gyr_params: ``NN_a`` / ``NN_phi`` parameters after the initial training.
        loss_acc, loss_gyr: their final initial-training MSE (g^2, (rad/s)^2).
    """

    acc_params: Params
    gyr_params: Params
    loss_acc: Float[Array, ""]
    loss_gyr: Float[Array, ""]


def _initial_training(
    acc: Float[Array, "M N 3"],
    gyr: Float[Array, "M N 3"],
    acc_spec: Diag,
    gyr_spec: Diag,
    hp: OnlineThesisHParams,
    init_every: int = INIT_EVERY,
) -> InitialTraining:
    """The initial training (4.3): every ``init_every``-th sequence, spec-converted targets (eq. 4.8).

    It reads only ``hp.key``, ``init_lr``, ``init_epochs`` and the two initial scales.
    """
    k_a, k_g = jax.random.split(hp.key)
    init_opt = optax.adam(hp.init_lr)

    def init_train(key, raw, cal, spec, scale):
        target = spec_convert(raw, spec)
        p0 = init_params(key, scale)
        loss_fn = lambda p: mse(target, cal(p, raw))  # noqa: E731
        p, _, loss = adam_steps(loss_fn, p0, init_opt.init(p0), init_opt, hp.init_epochs)
        return p, loss

    acc_p0, loss_a = init_train(k_a, acc[::init_every].reshape(-1, 3), partial(calibrate_acc, spec=acc_spec), acc_spec,
                                hp.acc_init_scale)
    gyr_p0, loss_g = init_train(k_g, gyr[::init_every].reshape(-1, 3), partial(calibrate_gyr, spec=gyr_spec), gyr_spec,
                                hp.gyr_init_scale)
    return InitialTraining(acc_p0, gyr_p0, loss_a, loss_g)


def _adaptive(
    acc: Float[Array, "M N 3"],
    gyr: Float[Array, "M N 3"],
    dt: Float[Array, ""],
    acc_spec: Diag,
    gyr_spec: Diag,
    hp: OnlineThesisHParams,
    val: Sequences | None,
    init: InitialTraining,
) -> OnlineThesisResult:
    """The adaptive loop (4.4-4.5) from ``init``: one ``lax.scan`` step per sequence (pure; jit/vmap-able)."""
    cal_a = partial(calibrate_acc, spec=acc_spec)
    cal_g = partial(calibrate_gyr, spec=gyr_spec)
    acc_p0, gyr_p0 = init.acc_params, init.gyr_params
    opt_g = optax.adam(hp.gyr_lr)
    opt_a = optax.adam(hp.acc_lr)

    def evaluate(acc_p, gyr_p):
        if val is None:
            return jnp.asarray(jnp.nan), jnp.asarray(jnp.nan)
        e_g = sequence_gyro_error(val.gyr_true, cal_g(gyr_p, val.gyr))
        e_a = sequence_acc_error(val.acc_true[:, -1], cal_a(acc_p, val.acc[:, -1]))
        return e_g, e_a

    def step(carry, seq):
        acc_p, gyr_p, s_a, s_g = carry
        a_raw, g_raw = seq
        # (a) gyroscope update, eq. 4.9-4.10: NN_a fixed.
        a_c = jax.lax.stop_gradient(cal_a(acc_p, a_raw))
        g_loss_fn = lambda p: gyro_loss(cal_g(p, g_raw), a_c, dt)  # noqa: E731
        gyr_p, s_g, l_g = adam_steps(g_loss_fn, gyr_p, s_g, opt_g, hp.gyr_steps)
        # (b) accelerometer update, eq. 4.11-4.13: NN_phi fixed, a_phi,N a fixed target.
        phi_c = jax.lax.stop_gradient(cal_g(gyr_p, g_raw))
        a_c1 = jax.lax.stop_gradient(cal_a(acc_p, a_raw[0]))
        a_loss_fn = lambda p: acc_loss(a_c1, cal_a(p, a_raw[-1]), phi_c, dt, hp.w)  # noqa: E731
        acc_p, s_a, l_a = adam_steps(a_loss_fn, acc_p, s_a, opt_a, hp.acc_steps)
        # (c) validation errors, eq. 4.14.
        e_g, e_a = evaluate(acc_p, gyr_p)
        return (acc_p, gyr_p, s_a, s_g), (l_g, l_a, e_g, e_a)

    carry0 = (acc_p0, gyr_p0, opt_a.init(acc_p0), opt_g.init(gyr_p0))
    (acc_p, gyr_p, _, _), (l_g, l_a, e_g, e_a) = jax.lax.scan(step, carry0, (acc, gyr))
    e_g0, e_a0 = evaluate(acc_p0, gyr_p0)
    return OnlineThesisResult(
        acc_params=acc_p,
        gyr_params=gyr_p,
        acc_params0=acc_p0,
        gyr_params0=gyr_p0,
        init_loss_acc=init.loss_acc,
        init_loss_gyr=init.loss_gyr,
        gyr_loss=l_g,
        acc_loss=l_a,
        e_g=jnp.concatenate([e_g0[None], e_g]),
        e_a=jnp.concatenate([e_a0[None], e_a]),
    )


def _online_thesis(
    acc: Float[Array, "M N 3"],
    gyr: Float[Array, "M N 3"],
    dt: Float[Array, ""],
    acc_spec: Diag,
    gyr_spec: Diag,
    hp: OnlineThesisHParams,
    val: Sequences | None,
    init_every: int = INIT_EVERY,
) -> OnlineThesisResult:
    """Initial training + one ``lax.scan`` over the ``M`` sequences (pure; jit/vmap-able)."""
    init = _initial_training(acc, gyr, acc_spec, gyr_spec, hp, init_every)
    return _adaptive(acc, gyr, dt, acc_spec, gyr_spec, hp, val, init)


def run_dataset(data: Dataset2, hp: OnlineThesisHParams, init_every: int = INIT_EVERY) -> OnlineThesisResult:
    """The pure (un-jitted) :func:`run_online_thesis`, to call inside a caller's ``jit``/``vmap``
    (e.g. vmapped over datasets and hyperparameters); arguments as there.

    Args:
        data: :class:`~jaxcal.sequences.Dataset2` (traced).
        hp: :class:`OnlineThesisHParams` (traced).
        init_every: (static: it sets a shape) stride of the sequences used for the initial training (thesis: 10).
    """
    dt = jnp.asarray(data.dt, dtype=jnp.float32)
    return _online_thesis(
        data.train.acc, data.train.gyr, dt, data.acc_spec, data.gyr_spec, hp, data.val, init_every
    )


def initial_training(data: Dataset2, hp: OnlineThesisHParams, init_every: int = INIT_EVERY) -> InitialTraining:
    """The initial training of :func:`run_dataset` alone (pure, un-jitted): it depends only on the data,
    ``hp.key``, ``init_lr``, ``init_epochs`` and the initial scales, so configurations that share those
    (a sweep of the online learning rates or ``w``) can share it (:func:`run_from_initial`).

    Args:
        data: :class:`~jaxcal.sequences.Dataset2` (traced).
        hp: :class:`OnlineThesisHParams` (traced).
        init_every: (static) stride of the sequences used for the initial training.
    """
    return _initial_training(data.train.acc, data.train.gyr, data.acc_spec, data.gyr_spec, hp, init_every)


def run_from_initial(data: Dataset2, hp: OnlineThesisHParams, init: InitialTraining) -> OnlineThesisResult:
    """The adaptive loop of :func:`run_dataset` from a given initial training (pure, un-jitted):
    ``run_from_initial(data, hp, initial_training(data, hp, e))`` is ``run_dataset(data, hp, e)``.

    Args:
        data: :class:`~jaxcal.sequences.Dataset2` (traced).
        hp: :class:`OnlineThesisHParams` (traced; its initial-training fields are not read).
        init: :func:`initial_training` of the same data.
    """
    dt = jnp.asarray(data.dt, dtype=jnp.float32)
    return _adaptive(data.train.acc, data.train.gyr, dt, data.acc_spec, data.gyr_spec, hp, data.val, init)


#: ``run_online_thesis(data, hp)``: the whole algorithm on a simulated Dataset 2, one ``jit``.
run_online_thesis = jax.jit(run_dataset, static_argnames=("init_every",))
run_online_thesis.__doc__ = """Run the thesis's online algorithm on Dataset 2 (one ``jit``).

Args:
    data: :class:`~jaxcal.sequences.Dataset2` (training sequences are processed in order; the
        validation sequences give ``e_g``, ``e_a`` at every iteration; no other label is used).
    hp: :class:`OnlineThesisHParams` (all traced: ``jax.vmap(run_online_thesis, (None, 0))``
        runs several trainings at once).
    init_every: (static) stride of the sequences used for the initial training (thesis: 10).

Returns:
    :class:`OnlineThesisResult` with ``e_g``, ``e_a`` of shape ``(n_train + 1,)``.
"""


@partial(jax.jit, static_argnames=("init_every",))
def run_sequences(acc, gyr, dt, acc_spec, gyr_spec, hp, init_every):
    """The algorithm on equal-length raw sequences without labels (``e_g``, ``e_a`` NaN), one ``jit``;
    what :func:`fit_online_thesis_recording` runs once it has split the recording.

    Args:
        acc, gyr: (M, N, 3) raw sequences (LSB).
        dt: sample period (s).
        acc_spec, gyr_spec: the datasheet sensor models.
        hp: :class:`OnlineThesisHParams` (traced).
        init_every: (static) stride of the sequences used for the initial training.
    """
    return _online_thesis(acc, gyr, dt, acc_spec, gyr_spec, hp, None, init_every)


def fit_online_thesis_recording(
    acc: Float[Array, "L 3"],
    gyr: Float[Array, "L 3"],
    seq: Int[Array, " L"],
    dt: float,
    acc_spec: Diag,
    gyr_spec: Diag,
    key: jax.Array,
    hp: OnlineThesisHParams | None = None,
    init_every: int = INIT_EVERY,
) -> OnlineThesisResult:
    """Run the online-thesis algorithm on a recording (no labels used).

    The recording must consist of sequences, each a rotation about the sensor's centre between two
    static orientations (section 4.2): contiguous ``seq`` ids of equal length (see
    :func:`jaxcal.sequences.split_equal`, which raises ``ValueError`` otherwise). Sequences are processed in
    the order they appear; every tenth is also used for the initial training.

    Args:
        acc, gyr: raw outputs (LSB).
        seq: sequence id of every sample.
        dt: sample period (s).
        acc_spec, gyr_spec: datasheet models for eq. 3.6 bounds and the eq. 4.8 initial targets.
        key: PRNG key (replaces ``hp.key``).
        hp: hyperparameters (default :func:`default_hparams`).
        init_every: stride of the sequences used for the initial training (thesis: 10).

    Returns:
        :class:`OnlineThesisResult` (``e_g``, ``e_a`` are NaN: no labels). Apply it with
        :func:`calibrate_acc` / :func:`calibrate_gyr` and the same specs.
    """
    a = jnp.asarray(split_equal(acc, seq), dtype=jnp.float32)
    g = jnp.asarray(split_equal(gyr, seq), dtype=jnp.float32)
    hp = default_hparams(key) if hp is None else hp._replace(key=key)
    dt_arr = jnp.asarray(dt, dtype=jnp.float32)
    return run_sequences(a, g, dt_arr, acc_spec, gyr_spec, hp, init_every=init_every)


def test_set_errors(
    result_params: tuple[Params, Params], data: Dataset2
) -> tuple[Float[Array, " La"], Float[Array, " Lg"]]:
    """Per-sample Euclidean errors (eq. 3.8) on the Dataset 2 test sets: ``(acc g, gyr rad/s)``.

    Args:
        result_params: ``(NN_a, NN_phi)`` parameters, e.g. ``(result.acc_params, result.gyr_params)``.
        data: the :class:`~jaxcal.sequences.Dataset2` whose test sets and specs are used.
    """
    acc_p, gyr_p = result_params
    e_a = euclidean_error(data.test_acc.true, calibrate_acc(acc_p, data.test_acc.raw, data.acc_spec))
    e_g = euclidean_error(data.test_gyr.true, calibrate_gyr(gyr_p, data.test_gyr.raw, data.gyr_spec))
    return e_a, e_g
