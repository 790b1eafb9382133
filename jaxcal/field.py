"""Field calibration: the streaming filter of :mod:`jaxcal.online` on a recording of rests joined by
hand motions, with no labels, no ``seq`` ids and no datasheet (the thesis's chapter-4 promise,
"in field without use of any external equipment", on real recordings).

Why the simulation's recipe fails in the field. :mod:`jaxcal.online` assumes what the thesis's
Dataset 2 holds: every accelerometer sample is gravity carried by the gyroscope (rotation about
the sensor's centre, both sensors sampled at once), and a datasheet as the starting point. Real
hand motions break the first (translational acceleration of 0.1-1 g, a lever arm, a time offset
between the two streams), and raw counts without a datasheet break the second (an unsigned 16-bit
offset of 33000 LSB, a scale guessed 40 % off). Both made ``online`` diverge or lose to the
factory calibration on every real recording (issue 26).

What this module does instead:

1. **Initialise from the data** (:func:`rest_init`): the accelerometer from the rests (``|f| = 1 g``,
   :func:`jaxcal.multipos.fit_prepared`) and the gyroscope from the gravity it carries between
   them; the datasheet is never the starting point (a wrong one cannot make the filter diverge),
   at most the prior centre of that fit (``MultiposConfig.prior``). ``online`` then holds the
   accelerometer there (``OnlineHP.acc_prior_factor``) and the filter corrects the gyroscope.
2. **Stream only what the model explains** (:func:`field_batch`): each sequence is one motion
   between two rests; the gyroscope is integrated through every sample of the motion, and the
   accelerometer residuals sit at the two rests (each rest's mean, weighted by its sample count:
   exactly the sum of its per-sample residuals when the body is still). The motion samples stay in
   the propagation with residual weight 0 (``residuals="rests"``, the default) or 1 (``"all"``,
   the simulation's recipe); ``results/field.md`` measures which holds out better. The physics that
   ``diagnose`` names in the field (lever arm, accelerometer-gyroscope time offset, translational
   acceleration) lives in the motion samples, so the rest residuals are immune to it.
3. **Hold out what it never saw** (:func:`fold_fits`): interleaved rest folds; fold ``k`` is
   initialised and streamed without its rests and the motions that touch them, so the held-out
   figure includes the initialisation (scored by :func:`jaxcal.eval.heldout.fold_errors`). The same folds score the initial guess, so a user sees
   whether the filter helped (and ``calibrate`` refuses a model that is worse than its own
   initial guess).

Everything is float64 (entered here). The batch has one shape for the full fit and every fold
(a fold skips sequences by zero weights), so a recording compiles once.

Dimension letters: ``P`` rests, ``J = P - 1`` motions, ``M`` usable motions (sequences), ``N``
samples per sequence, ``F`` folds.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxcal import multipos as mp
from jaxcal.online import OnlineHP, SequenceBatch, make_filter, online_scan, to_linear_cal
from jaxcal.precision import float64
from jaxcal.sensor import Diag, LinearCal

__all__ = ["RESIDUALS", "FieldBatch", "FieldInit", "FoldFits", "GsensChoice", "carried_sigma", "choose_gsens", "compose",
           "field_batch", "fit_field", "fold_fits", "rest_init", "rest_init_chosen", "rest_noise", "sequence_weights"]

RESIDUALS = ("rests", "all")


class FieldInit(NamedTuple):
    """A calibration from the data alone (:func:`rest_init`): ``acc`` and ``gyr`` applied forms
    (recorded units to g and rad/s) and the gyroscope's g-sensitivity ``G`` ((rad/s)/g, zero unless
    fitted): ``w = A_g (y_g - b_g) - G f``, ``f`` the calibrated accelerometer."""

    acc: LinearCal
    gyr: LinearCal
    G: np.ndarray


@float64
def rest_init(data: mp.MultiposData, acc_w: np.ndarray | None = None, gyr_w: np.ndarray | None = None,
              config: mp.MultiposConfig = mp.MultiposConfig()) -> FieldInit:
    """The initial calibration from the data alone: the accelerometer from the rests' ``|f| = 1 g``,
    the gyroscope bias (and, with ``config.g_sensitivity``, its g-sensitivity) from the rests and its
    matrix from the gravity carried between them (:func:`jaxcal.multipos.fit_prepared`, float64).

    Args:
        data: the rests and motions (:func:`jaxcal.multipos.prepare`, recorded units).
        acc_w: (P,) 0/1 weight per rest (``None``: all).
        gyr_w: (J,) 0/1 weight per motion (``None``: all usable).
        config: :class:`~jaxcal.multipos.MultiposConfig` (static).

    Returns:
        :class:`FieldInit` (numpy float64).
    """
    d = jax.tree_util.tree_map(jnp.asarray, data)
    P = d.pose_acc.shape[0]
    aw = jnp.ones(P) if acc_w is None else jnp.asarray(acc_w, jnp.float64)
    gw = jnp.ones(P - 1) if gyr_w is None else jnp.asarray(gyr_w, jnp.float64)
    f = mp.fit_prepared_jit(d, config, acc_w=aw, gyr_w=gw)
    return FieldInit(LinearCal(np.asarray(f.acc.A), np.asarray(f.acc.b)),
                     LinearCal(np.asarray(f.gyr.A), np.asarray(f.gyr.b)), np.asarray(f.gsens))


def rest_noise(acc: np.ndarray, intervals: np.ndarray, cal: LinearCal) -> float:
    """The accelerometer's noise at rest (g): each rest's per-axis standard deviation of the
    calibrated output, averaged over axes and rests (the filter's ``sigma_acc`` between rests).

    Args:
        acc: (L, 3) raw accelerometer.
        intervals: (P, 2) rest sample ranges ``[start, stop)``.
        cal: the accelerometer's applied calibration (raw to g).
    """
    a = np.asarray(acc, np.float64)
    A, b = np.asarray(cal.A, np.float64), np.asarray(cal.b, np.float64)
    return float(np.mean([((a[s:e] - b) @ A.T).std(0).mean() for s, e in np.asarray(intervals, int)]))


class GsensChoice(NamedTuple):
    """Whether the rests ask for the gyroscope's g-sensitivity (:func:`choose_gsens`).

    Args:
        chosen: the rests' gyroscope means are predicted better with it, by the one-standard-error rule.
        loo_bias: mean squared leave-one-rest-out error of the rests' gyroscope means with a bias
            alone (recorded gyro units squared, rests weighted by their sample counts).
        loo_gsens: the same with bias plus g-sensitivity ``b + H f``.
        se_gsens: the standard error of ``loo_gsens`` over the rests.
        n_rests: rests in the comparison.
    """

    chosen: bool
    loo_bias: float
    loo_gsens: float
    se_gsens: float
    n_rests: int


#: fewest rests for the comparison: ``b + H f`` has 4 coefficients per axis, and leaving one rest out
#: must leave more than that.
GSENS_MIN_RESTS = 6


def choose_gsens(data: mp.MultiposData, acc: LinearCal, acc_w: np.ndarray | None = None) -> GsensChoice:
    """Does the gyroscope's g-sensitivity belong in the model? Asked of the rests alone.

    At rest the true rate is zero, so each rest's mean gyroscope output is the bias, plus ``H f``
    where the gyroscope is g-sensitive (:func:`jaxcal.multipos.rest_gsens`). Each rest in turn is
    left out, both models are fitted to the others, and the left-out rest's mean is predicted.
    The richer model is chosen only where its mean squared error plus one standard error stays
    below the bias model's (the one-standard-error rule: Hastie, Tibshirani and Friedman, *The
    Elements of Statistical Learning*, 2nd ed., section 7.10). On the three real recordings of
    ``results/field.md`` it chooses the g-sensitivity on the Xsens session (held out 0.131 deg
    against 0.470 without it) and not on the MPU-6050 (3.84 against 3.04) or imucal's session
    (0.364 against 0.359).

    Args:
        data: the rests (:func:`jaxcal.multipos.prepare`; ``pose_acc``, ``pose_gyr``, ``pose_n``).
        acc: the accelerometer's applied calibration (recorded units to g).
        acc_w: (P,) 0/1 per rest (``None``: all); a 0 leaves a rest out of the comparison.
    """
    y = np.asarray(data.pose_gyr, np.float64)
    f = (np.asarray(data.pose_acc, np.float64) - np.asarray(acc.b, np.float64)) @ np.asarray(acc.A, np.float64).T
    n = np.asarray(data.pose_n, np.float64)
    keep = np.ones(len(y), bool) if acc_w is None else np.asarray(acc_w) > 0
    y, f, n = y[keep], f[keep], n[keep]
    P = len(y)
    if P < GSENS_MIN_RESTS:
        return GsensChoice(False, float("nan"), float("nan"), float("nan"), P)
    w = n / n.mean()
    x1 = np.concatenate([np.ones((P, 1)), f], axis=1)
    err = np.zeros((2, P))
    for k in range(P):
        m = np.arange(P) != k
        sw = np.sqrt(w[m])[:, None]
        for i, x in enumerate((x1[:, :1], x1)):
            coef = np.linalg.lstsq(x[m] * sw, y[m] * sw, rcond=None)[0]
            err[i, k] = np.sum((y[k] - x[k] @ coef) ** 2)
    e0, e1 = w * err[0], w * err[1]
    se1 = float(e1.std(ddof=1) / np.sqrt(P))
    return GsensChoice(bool(e1.mean() + se1 < e0.mean()), float(e0.mean()), float(e1.mean()), se1, P)


def rest_init_chosen(data: mp.MultiposData, acc_w: np.ndarray | None = None, gyr_w: np.ndarray | None = None,
                     config: mp.MultiposConfig = mp.MultiposConfig(), auto: bool = True,
                     choose_w: np.ndarray | None = None) -> tuple[FieldInit, GsensChoice | None]:
    """:func:`rest_init`, with the gyroscope's g-sensitivity chosen by the rests (:func:`choose_gsens`)
    where ``config`` leaves it out and ``auto`` is on: fitted without it, asked, and fitted again
    with it where the rests choose it. Returns the initial calibration and the choice (``None``
    where none was asked).

    Args:
        data, acc_w, gyr_w, config: as :func:`rest_init`.
        auto: let the rests choose the g-sensitivity.
        choose_w: (P,) 0/1 per rest taking part in the choice (``None``: ``acc_w``).
    """
    init = rest_init(data, acc_w, gyr_w, config)
    if not auto or config.g_sensitivity:
        return init, None
    choice = choose_gsens(data, init.acc, acc_w if choose_w is None else choose_w)
    if choice.chosen:
        init = rest_init(data, acc_w, gyr_w, config._replace(g_sensitivity=True))
    return init, choice


class FieldBatch(NamedTuple):
    """A recording's motions as filter sequences, in *raw* units (calibrated per fit, since the
    initialisation differs between folds).

    Args:
        acc: (J, N, 3) raw accelerometer; sequence ``j`` is the motion between rests ``j`` and
            ``j + 1``: row 0 the mean of the rest before it, rows ``1..n`` the motion's samples, row
            ``n + 1`` the mean of the rest after it; padded.
        gyr: (J, N, 3) raw gyroscope rates of the same rows, midpoint of two samples (row 0: the
            rest's last sample and the motion's first), so that the propagation integrates the
            motion from the last rest sample to the first of the next.
        mask: (J, N) 1 on rows, 0 on padding.
        rest_n: (J, 2) samples in the rest before and after (the weight of rows 0 and ``n + 1``).
        last: (J,) index of the last row (``n + 1``).
        usable: (J,) bool, the motion's samples and the rest after it are in the sequence (else
            only the rest before it).
    """

    acc: np.ndarray
    gyr: np.ndarray
    mask: np.ndarray
    rest_n: np.ndarray
    last: np.ndarray
    usable: np.ndarray


def field_batch(acc: np.ndarray, gyr: np.ndarray, intervals: np.ndarray, usable: np.ndarray) -> FieldBatch:
    """Every motion between consecutive rests as a sequence (:class:`FieldBatch`). An unusable
    motion (e.g. a saturated gyro) keeps only the rest before it, so that the rest still gives its
    ``|f| = 1 g`` row (one row: its direction is the sequence's free start, :func:`sequence_weights`).

    Args:
        acc, gyr: (L, 3) raw outputs.
        intervals: (P, 2) rest sample ranges ``[start, stop)``, in time order.
        usable: (P - 1,) bool, motion ``j`` is used (e.g. its gyro does not saturate).
    """
    acc, gyr = np.asarray(acc, np.float64), np.asarray(gyr, np.float64)
    iv = np.asarray(intervals, int)
    usable = np.asarray(usable, bool)
    if len(iv) < 2:
        raise ValueError("fewer than two rests")
    J = len(iv) - 1
    n_rows = [int(iv[j + 1, 0] - iv[j, 1]) + 2 if usable[j] else 1 for j in range(J)]
    N = max(n_rows)
    a, g = np.zeros((J, N, 3)), np.zeros((J, N, 3))
    mask, rest_n, last = np.zeros((J, N)), np.zeros((J, 2)), np.zeros(J, int)
    for j in range(J):
        s0, s1 = iv[j]
        e0, e1 = iv[j + 1]
        n = n_rows[j]
        a[j, 0], g[j, 0] = acc[s0:s1].mean(0), 0.5 * (gyr[s1 - 1] + gyr[s1])
        if usable[j]:
            a[j, 1:n - 1], g[j, 1:n - 1] = acc[s1:e0], 0.5 * (gyr[s1:e0] + gyr[s1 + 1:e0 + 1])
            a[j, n - 1], g[j, n - 1] = acc[e0:e1].mean(0), gyr[e0]
        a[j, n:], g[j, n:] = a[j, n - 1], g[j, n - 1]  # padding repeats the last row (masked out)
        mask[j, :n] = 1.0
        rest_n[j] = (s1 - s0, e1 - e0)
        last[j] = n - 1
    return FieldBatch(a, g, mask, rest_n, last, usable.copy())


def compose(outer: LinearCal, inner: LinearCal) -> LinearCal:
    """``x = A_o (A_i (y - b_i) - b_o)`` as one :class:`~jaxcal.sensor.LinearCal`:
    ``A = A_o A_i``, ``b = b_i + A_i^{-1} b_o``."""
    A_o, b_o, A_i, b_i = (np.asarray(v, np.float64) for v in (outer.A, outer.b, inner.A, inner.b))
    return LinearCal(A_o @ A_i, b_i + np.linalg.solve(A_i, b_o))


@float64
def carried_sigma(init: FieldInit, data: mp.MultiposData, motion_w: np.ndarray) -> float:
    """Per-component std (rad) of the gravity direction that ``init``'s gyroscope carries from one
    rest to the next, from its angles on the motions of weight 1: ``sqrt(mean(angle^2) / 2)``
    (two tangential components). On real motions this is the dominant error of a carried
    direction (Xsens: ~0.5 deg, against ~0.002 deg of accelerometer noise in a rest's mean)."""
    d = jax.tree_util.tree_map(jnp.asarray, data)
    a, g = (LinearCal(jnp.asarray(c.A, jnp.float64), jnp.asarray(c.b, jnp.float64)) for c in init[:2])
    ang = np.asarray(mp.gyro_angle_errors_jit(g, jnp.asarray(init.G, jnp.float64), a, d))
    ok = (np.asarray(motion_w) > 0) & np.asarray(data.seg_ok, bool) & np.isfinite(ang)
    return float(np.sqrt(np.mean(ang[ok] ** 2) / 2.0)) if ok.any() else 0.0


def sequence_weights(batch: FieldBatch, seq_w: np.ndarray, residuals: str, sigma: float,
                     sigma_dir: float) -> tuple[np.ndarray, np.ndarray]:
    """(J, N) residual weights along and across the predicted direction (:class:`~jaxcal.online.SequenceBatch`).

    A rest's ``|f|`` (along) counts once, with its sample count ``n``: at the end of the usable
    sequence before it when that one is streamed, else at the start of its own. Across: the start
    rest ``n`` (its direction is the sequence's free start ``f_0``, so this costs nothing) and the
    end rest ``1 / (1/n + sigma_dir^2 / sigma^2)`` (the gyroscope's carrying error). Motion rows: 0
    (``"rests"``) or 1 (``"all"``). A sequence with ``seq_w`` 0: all 0 (skipped)."""
    on = np.asarray(seq_w, np.float64) > 0
    use = np.asarray(batch.usable, bool)
    w = batch.mask * (1.0 if residuals == "all" else 0.0)
    wt = w.copy()
    J = np.arange(len(batch.last))
    n0, n1 = batch.rest_n[:, 0], batch.rest_n[:, 1]
    covered = np.concatenate([[False], on[:-1] & use[:-1]])
    w[J, 0], wt[J, 0] = np.where(covered, 0.0, n0), n0
    e = J[use]
    w[e, batch.last[e]] = n1[e]
    wt[e, batch.last[e]] = 1.0 / (1.0 / n1[e] + (sigma_dir / sigma) ** 2)
    return w * on[:, None], wt * on[:, None]


@float64
def fit_field(batch: FieldBatch, init: FieldInit, dt: float, hp: OnlineHP, kind: str = "diag",
              residuals: str = "rests", seq_w: np.ndarray | None = None,
              sigma_dir: float = 0.0) -> FieldInit:
    """The filter streamed over ``batch``'s sequences in order, starting at ``init``.

    The raw data are calibrated with ``init`` first (the gyroscope's g-sensitivity taken out with
    the initially calibrated accelerometer), so the filter's prior centre (``theta = 0``) is the
    initial calibration and its parameters are small corrections to it (its spec is the identity);
    the result is the composition of the two. ``kind="diag"`` (the default) corrects scales and
    biases and keeps the initial cross-axis terms: on the MPU-6050, whose poses never mix x and y,
    an affine filter that also corrected the accelerometer fitted its cross-axis terms to the
    gyroscope's carrying errors (held out 3.56 mg against 0.94 mg, ``results/field.md`` before
    2026-11-28). ``hp.acc_prior_factor = HOLD`` (``online``'s default between rests) holds the
    accelerometer at ``init`` and corrects the gyroscope alone.

    Args:
        batch: :func:`field_batch`.
        init: :class:`FieldInit` (:func:`rest_init`).
        dt: sample period (s).
        hp: :class:`~jaxcal.online.OnlineHP`; ``sigma_acc`` is one sample's noise in g.
        kind: ``"affine"`` or ``"diag"`` (static).
        residuals: ``"rests"`` or ``"all"`` (:func:`sequence_weights`).
        seq_w: (J,) 0/1 per sequence (``None``: all); a 0 skips the sequence.
        sigma_dir: per-component std (rad) of a carried gravity direction (:func:`carried_sigma`);
            0: the accelerometer's noise alone, the simulation's assumption.

    Returns:
        :class:`FieldInit`: the final calibration (``G`` carried through the gyroscope's correction).
    """
    ua, ug, w, wt = _inputs(batch, init, hp, residuals, seq_w, sigma_dir)
    theta = _pass(*(jnp.asarray(x, jnp.float64) for x in (ua, ug, batch.mask, w, wt)), jnp.asarray(dt, jnp.float64),
                  OnlineHP(*[jnp.asarray(v) for v in hp]), kind)
    return _result(theta, init, kind)


def _inputs(batch: FieldBatch, init: FieldInit, hp: OnlineHP, residuals: str, seq_w: np.ndarray | None,
            sigma_dir: float) -> tuple[np.ndarray, ...]:
    """The filter's inputs: ``batch`` calibrated with ``init`` and its residual weights."""
    if residuals not in RESIDUALS:
        raise ValueError(f"residuals must be one of {RESIDUALS}, got {residuals!r}")
    seq_w = np.ones(len(batch.last)) if seq_w is None else np.asarray(seq_w, np.float64)
    ia, ig, G = init
    ua = (batch.acc - np.asarray(ia.b)) @ np.asarray(ia.A).T
    ug = (batch.gyr - np.asarray(ig.b)) @ np.asarray(ig.A).T - ua @ np.asarray(G).T
    w, wt = sequence_weights(batch, seq_w, residuals, float(hp.sigma_acc), float(sigma_dir))
    return ua, ug, w, wt


@partial(jax.jit, static_argnames=("kind",))
def _pass(ua, ug, mask, w, wt, dt, hp: OnlineHP, kind: str):
    """The filter's final ``theta`` from the identity spec (pure; ``kind`` static)."""
    state0 = make_filter(kind).init(hp, ua.dtype)
    state, _ = online_scan(state0, SequenceBatch(ua, ug, mask, w, wt), dt, hp, kind)
    return state.theta


def _result(theta, init: FieldInit, kind: str) -> FieldInit:
    """The composition of the filter's correction ``theta`` with ``init`` (call under x64)."""
    one = Diag(jnp.ones(3, jnp.float64), jnp.zeros(3, jnp.float64))
    ca, cg = to_linear_cal(theta, kind, one, one)
    ca, cg = (LinearCal(np.asarray(c.A), np.asarray(c.b)) for c in (ca, cg))
    return FieldInit(compose(ca, init.acc), compose(cg, init.gyr), np.asarray(cg.A) @ np.asarray(init.G))


class FoldFits(NamedTuple):
    """Held-out fits of :func:`fold_fits`.

    Args:
        rest_fold: (P,) fold of each rest (-1: the initial rest, in every fold's training set).
        init: per fold, the :class:`FieldInit` fitted without the fold's rests and motions.
        final: per fold, the filter's :class:`FieldInit` from that initial guess.
        n_seq: (F,) sequences streamed per fold.
        determined: (F,) bool, the fold's remaining rests determine the accelerometer
            (:func:`jaxcal.multipos.observability` at the initial fit on all rests); an undetermined
            fold's scores would be an extrapolation and are not held-out figures (as
            ``multipos``'s, e.g. the only rest with one axis down in a six-face session).
        gsens: (F,) bool, the fold's model holds the gyroscope's g-sensitivity (``config``'s, or
            chosen from the fold's own rests with ``gsens_auto``, :func:`choose_gsens`).
    """

    rest_fold: np.ndarray
    init: list
    final: list
    n_seq: np.ndarray
    determined: np.ndarray
    gsens: np.ndarray | None = None


@float64
def fold_fits(data: mp.MultiposData, batch: FieldBatch, dt: float, hp: OnlineHP, n_folds: int, kind: str = "diag",
              residuals: str = "rests", config: mp.MultiposConfig = mp.MultiposConfig(),
              whole: FieldInit | None = None, gsens_auto: bool = False) -> FoldFits:
    """Interleaved rest folds (the initial rest in none: every fold's stream starts from it).
    Fold ``k`` leaves out its rests (from the initial accelerometer fit), the motions that start
    or end at them (from the initial gyroscope fit and from the stream), and is scored on exactly
    those by the caller.

    Args:
        data: the rests and motions (:func:`jaxcal.multipos.prepare`) the batch was cut from.
        batch: :func:`field_batch` of the same rests.
        dt: sample period (s).
        hp: :class:`~jaxcal.online.OnlineHP`.
        n_folds: number of folds (at most ``P - 1``).
        kind, residuals, config: as :func:`fit_field` and :func:`rest_init`.
        whole: :func:`rest_init` on all the rests with ``config``, if the caller has it (``None``:
            fitted here); the point at which each fold's observability is read.
        gsens_auto: where ``config`` leaves the g-sensitivity out, let each fold's own rests choose
            it (:func:`choose_gsens`), as the fit on the whole recording does; the held-out rests
            never take part in the choice.
    """
    P = data.pose_acc.shape[0]
    F = min(int(n_folds), P - 1)
    pf = np.concatenate([[-1], mp.fold_ids(P - 1, F)])
    seg_ok = np.asarray(data.seg_ok, bool) & np.asarray(batch.usable, bool)
    whole = rest_init(data, config=config) if whole is None else whole
    inits, n_seq, det, ins, gs = [], [], [], [], []
    for k in range(F):
        aw = (pf != k).astype(np.float64)
        det.append(bool(mp.observability(data, whole.acc, whole.gyr, acc_w=aw).acc_sv.min() >= mp.OBSERVABLE_TOL))
        both = (pf[:-1] != k) & (pf[1:] != k)
        mw = (both & seg_ok).astype(np.float64)
        if mw.sum() < 2:
            raise ValueError(f"fold {k + 1} of {F} keeps {int(mw.sum())} motions; too few rests for held-out folds")
        init, choice = rest_init_chosen(data, aw, mw, config, gsens_auto)
        gs.append(bool(config.g_sensitivity) or (choice is not None and choice.chosen))
        inits.append(init)
        ins.append(_inputs(batch, init, hp, residuals, both.astype(np.float64), carried_sigma(init, data, mw)))
        n_seq.append(int(mw.sum()))
    # one fold after another: a vmap over the folds ran 2x slower on 2 CPU cores (61.6 s against
    # 30.9 s on the Xsens session, the same load), as multipos's folds (multipos.heldout.fold_batch)
    mask, dt64 = jnp.asarray(batch.mask, jnp.float64), jnp.asarray(dt, jnp.float64)
    hp64 = OnlineHP(*[jnp.asarray(v) for v in hp])
    finals = [_result(_pass(*(jnp.asarray(x, jnp.float64) for x in (ua, ug)), mask,
                            *(jnp.asarray(x, jnp.float64) for x in (w, wt)), dt64, hp64, kind), init, kind)
              for (ua, ug, w, wt), init in zip(ins, inits)]
    return FoldFits(pf, inits, finals, np.asarray(n_seq), np.asarray(det, bool), np.asarray(gs, bool))
