"""Multi-position self-calibration (Tedaldi, Pretto, Menegatti, ICRA 2014; the imu_tk method).

No labels and no datasheet values are needed: the user holds the IMU still in many orientations
and turns it by hand in between.

* **Accelerometer** (from the static poses): ``f = A (y - b)`` with ``|f| = 1 g`` in every pose.
  ``model="9"`` is imu_tk's 9 parameters, ``A = T diag(k)`` with ``T`` unit lower-triangular
  (3 non-orthogonality terms), 3 scales, 3 biases. ``model="12"`` frees all of ``A`` (12
  parameters); the ``|f|`` residual is blind to a rotation ``A -> Q A`` (3 gauge directions), so
  the antisymmetric part of ``A`` is pinned by a residual ``A - A^T``, which costs nothing at the
  optimum. The two therefore reach the same ``|f|`` fit: they differ in the frame they report.
* **Gyroscope** (from the motions between poses): ``w = G (y_g - b_g) [- G_s f]`` with a full
  ``G`` (9 parameters: scales and misalignment w.r.t. the accelerometer frame), the bias ``b_g``
  from the static intervals, and optionally the g-sensitivity ``G_s`` (9 more). The rates are
  integrated between consecutive static poses, ``R = prod_n Exp(w_n dt_n)`` (midpoint rate,
  uneven ``dt`` kept; samples are grouped in blocks whose rotation vector is the second-order
  Magnus sum, precomputed once from the raw data, see :class:`MultiposData`; blocks of 8 change
  the Xsens angles by < 0.001 deg against the per-sample product), and under the physical convention (``CONVENTIONS.md``) the gravity
  direction measured in pose ``j`` must be carried onto pose ``j + 1``: ``R^T u_j = u_{j+1}``.

Optional extra gyro rows: sections of known rotation (:class:`KnownRotations`, e.g. a closed
turn, ``R_known = I``) and whole turns about the vertical (:class:`VerticalTurns`, e.g. the IMU
turned flat on a table, as in Ferraris' protocol, but unlabelled: the turning axis is the gravity
direction the calibrated accelerometer measures at the rests next to the turn).

Everything is initialised from the data: the accelerometer from an axis-aligned ellipsoid fit of
the pose means (fallback: per-axis min/max), the gyro scale from a grid search over
``G = s I`` (both signs, 1e-7 .. 10 unit/LSB) of the same residual. Both fits are
``optimistix.LevenbergMarquardt`` least squares on pure residual functions, run in float64 and
vmappable over per-pose / per-transition weights (used for leave-poses-out folds).

Data flow: :func:`prepare` (numpy, turns a recording plus static intervals into padded arrays),
:func:`fit_prepared` (pure JAX), :func:`fit_multipos` (both), :func:`fit_multipos_recording`
(interval detection with imu_tk's threshold scan, then the fit; returns forward-model
:class:`~jaxcal.sensor.Affine` pairs for ``jaxcal calibrate --method multipos``).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Bool, Float

from jaxcal.rotation import exp_so3, hat, log_so3
from jaxcal.sensor import Affine
from jaxcal.static import detect_static


class MultiposConfig(NamedTuple):
    """Options. ``acc_model``: ``"9"`` or ``"12"``. ``gyro_bias``: ``"static"`` (mean over the
    static intervals in use) or ``"init"`` (the first interval only, as imu_tk). ``g_sensitivity``:
    also fit ``G_s``. ``midpoint``: midpoint rates (else the left sample, zero-order hold).
    ``max_steps``: LM iteration cap. ``prior``: optional :class:`DatasheetPrior` (MAP on scales
    and cross-axis terms; ``None``, the default, uses the data alone). ``acc_ridge``: weak ridge on
    the accelerometer's cross-axis terms (see :func:`fit_acc`; 0 turns it off). ``acc_fit``:
    ``"full"`` (:func:`fit_acc`) or ``"determined"`` (:func:`fit_acc_determined`: move the
    recording's own units only along the combinations the poses determine; 9-parameter model).
    ``gyr_fit``: ``"full"`` or ``"none"`` (the gyroscope stays as recorded: ``G = I``, ``b = 0``)."""

    acc_model: str = "9"
    gyro_bias: str = "static"
    g_sensitivity: bool = False
    midpoint: bool = True
    max_steps: int = 100
    prior: Any = None
    acc_ridge: float = 1e-2
    acc_fit: str = "full"
    gyr_fit: str = "full"


class InverseAffine(NamedTuple):
    """Calibration in the applied direction ``x = A (y - b)`` (``A`` unit/LSB, ``b`` LSB)."""

    A: Float[Array, "3 3"]
    b: Float[Array, "3"]


class MultiposData(NamedTuple):
    """Padded arrays of one recording (see :func:`prepare`). ``P`` poses, ``J = P - 1``
    transitions of at most ``L`` blocks. Units are the recording's (raw or physical).

    A transition is cut into blocks of ``block`` samples; with ``a_i = y_i dt_i`` (the gyro's rate
    point times the step) a block stores ``sy = sum a_i``, ``sdt = sum dt_i``,
    ``c0 = sum_{i<j} a_i x a_j``, ``p1 = sum_{i<j} dt_i a_j`` and ``p2 = sum_{i<j} a_i dt_j``. For
    any calibration ``w = G (y - b)`` the block's rotation vector to second order (Magnus / BCH,
    error O(|w dt|^3) per block) is ``G (sy - b sdt) + cof(G) (c0 - b x p1 + b x p2) / 2``, using
    ``(G u) x (G v) = cof(G) (u x v)``: raw data are summed once, every fit step is cheap.
    """

    pose_acc: Float[Array, "P 3"]  # mean accelerometer output per static pose
    pose_gyr: Float[Array, "P 3"]  # mean gyroscope output per static pose
    pose_n: Float[Array, "P"]  # samples per pose
    sy: Float[Array, "J L 3"]
    sdt: Float[Array, "J L"]
    c0: Float[Array, "J L 3"]
    p1: Float[Array, "J L 3"]
    p2: Float[Array, "J L 3"]
    sacc: Float[Array, "J L 3"]  # block sums of accelerometer output * dt (g-sensitivity)
    seg_ok: Bool[Array, "J"]  # False: transition unusable (saturated gyro)


class MultiposFit(NamedTuple):
    """Result: ``acc``/``gyr`` calibrations (applied direction), ``gsens`` (3, 3) ((rad/s)/g, zero
    unless fitted), and the final residual norms of the two least-squares problems."""

    acc: InverseAffine
    gyr: InverseAffine
    gsens: Float[Array, "3 3"]
    acc_cost: Float[Array, ""]
    gyr_cost: Float[Array, ""]


# ------------------------------------------------------------------------------ preparation


def _segment_sums(
    t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, spans: list, midpoint: bool, block: int, gyr_limit: float | None
) -> tuple[dict, np.ndarray, np.ndarray]:
    """Block sums (see :class:`MultiposData`) of the integration spans ``[a, b]`` (sample ``a`` to
    sample ``b``), padded to a common number of blocks; and the usable flag of each span."""
    J = len(spans)
    L = max(1, max(-(-(b - a) // block) for a, b in spans))
    out = {k: np.zeros((J, L, 3)) for k in ("sy", "c0", "p1", "p2", "sacc")}
    sdt = np.zeros((J, L))
    seg_ok = np.ones(J, bool)
    for j, (a, b) in enumerate(spans):
        n = b - a
        y = 0.5 * (gyr[a:b] + gyr[a + 1 : b + 1]) if midpoint else gyr[a:b]
        f = 0.5 * (acc[a:b] + acc[a + 1 : b + 1]) if midpoint else acc[a:b]
        dt = t[a + 1 : b + 1] - t[a:b]
        pad = (-n) % block
        y = np.concatenate([y, np.zeros((pad, 3))]).reshape(-1, block, 3)
        f = np.concatenate([f, np.zeros((pad, 3))]).reshape(-1, block, 3)
        dt = np.concatenate([dt, np.zeros(pad)]).reshape(-1, block)
        av = y * dt[..., None]
        ca = np.cumsum(av, axis=1) - av  # sum_{i<j} a_i, at j
        cd = (np.cumsum(dt, axis=1) - dt)[..., None]  # sum_{i<j} dt_i, at j
        nb = av.shape[0]
        out["sy"][j, :nb] = av.sum(1)
        out["c0"][j, :nb] = np.cross(ca, av).sum(1)
        out["p1"][j, :nb] = (cd * av).sum(1)
        out["p2"][j, :nb] = (ca * dt[..., None]).sum(1)
        out["sacc"][j, :nb] = (f * dt[..., None]).sum(1)
        sdt[j, :nb] = dt.sum(1)
        if gyr_limit is not None and np.any(np.abs(gyr[a : b + 1]) >= gyr_limit):
            seg_ok[j] = False
    return out, sdt, seg_ok


def prepare(
    t: np.ndarray,
    acc: np.ndarray,
    gyr: np.ndarray,
    intervals: np.ndarray,
    *,
    gyr_limit: float | None = None,
    midpoint: bool = True,
    block: int = 8,
    spans: np.ndarray | None = None,
) -> MultiposData:
    """Pose means and padded transition segments (numpy; shapes depend on the data).

    Args:
        t: (N,) times (s), increasing, uneven allowed.
        acc, gyr: (N, 3) outputs (LSB or physical).
        intervals: (P, 2) static ``[start, stop)`` sample indices, in time order.
        gyr_limit: if given, a transition with any ``|gyr| >= gyr_limit`` is marked unusable.
        midpoint: rate point of step ``n`` is ``(y_n + y_{n+1}) / 2`` (else ``y_n``).
        block: samples per integration block (1: exact per-sample product, first order).
        spans: optional (P - 1, 2) integration spans ``[a, b]`` of the transitions (default: from
            the last sample of pose ``j`` to the first of pose ``j + 1``). Pass them when the pose
            means use only part of a static hold (e.g. a time split), so that the transitions
            start and end where the body really moved.
    """
    t = np.asarray(t, np.float64)
    acc = np.asarray(acc, np.float64)
    gyr = np.asarray(gyr, np.float64)
    iv = np.asarray(intervals, np.int64).reshape(-1, 2)
    if len(iv) < 2:
        raise ValueError("multipos needs at least two static intervals")
    pose_acc = np.stack([acc[a:b].mean(0) for a, b in iv])
    pose_gyr = np.stack([gyr[a:b].mean(0) for a, b in iv])
    pose_n = (iv[:, 1] - iv[:, 0]).astype(np.float64)
    # transition j: from the last sample of pose j to the first sample of pose j + 1
    if spans is None:
        spans = [(iv[j, 1] - 1, iv[j + 1, 0]) for j in range(len(iv) - 1)]
    else:
        spans = [(int(a), int(b)) for a, b in np.asarray(spans).reshape(-1, 2)]
        if len(spans) != len(iv) - 1:
            raise ValueError(f"spans: need {len(iv) - 1} transitions, got {len(spans)}")
    out, sdt, seg_ok = _segment_sums(t, acc, gyr, spans, midpoint, block, gyr_limit)
    return MultiposData(pose_acc, pose_gyr, pose_n, out["sy"], sdt, out["c0"], out["p1"], out["p2"],
                        out["sacc"], seg_ok)


class KnownRotations(NamedTuple):
    """Sections of known body rotation (e.g. a closed 360 deg turn on a turntable or against a
    table edge): block sums as in :class:`MultiposData` for ``K`` sections, and the known rotation
    ``R`` (K, 3, 3) of each, in the physical convention: ``R = R(t_0)^T R(t_1)`` (body frame, the
    product ``prod Exp(w dt)`` the gyro must integrate to). A closed turn has ``R = I``."""

    sy: Float[Array, "K L 3"]
    sdt: Float[Array, "K L"]
    c0: Float[Array, "K L 3"]
    p1: Float[Array, "K L 3"]
    p2: Float[Array, "K L 3"]
    sacc: Float[Array, "K L 3"]
    R: Float[Array, "K 3 3"]
    seg_ok: Bool[Array, "K"]


def prepare_known(
    t: np.ndarray,
    acc: np.ndarray,
    gyr: np.ndarray,
    spans: np.ndarray,
    rotvecs: np.ndarray,
    *,
    gyr_limit: float | None = None,
    midpoint: bool = True,
    block: int = 8,
) -> KnownRotations:
    """Known-rotation sections (numpy). ``spans`` (K, 2): first and last sample ``[a, b]`` of each
    section; ``rotvecs`` (K, 3): its known body rotation vector (rad; ``exp_so3`` of it is ``R``);
    a closed turn of any whole number of revolutions is ``0`` (or ``2 pi`` times the axis)."""
    t = np.asarray(t, np.float64)
    acc = np.asarray(acc, np.float64)
    gyr = np.asarray(gyr, np.float64)
    sp = [(int(a), int(b)) for a, b in np.asarray(spans).reshape(-1, 2)]
    out, sdt, ok = _segment_sums(t, acc, gyr, sp, midpoint, block, gyr_limit)
    with jax.enable_x64(True):
        r = np.asarray(exp_so3(jnp.asarray(np.asarray(rotvecs, np.float64).reshape(-1, 3))))
    return KnownRotations(out["sy"], sdt, out["c0"], out["p1"], out["p2"], out["sacc"], r, ok)


class VerticalTurns(NamedTuple):
    """Whole turns about the vertical, e.g. the IMU turned flat on a table (the rotations of
    Ferraris' protocol), used **without labels**: during such a turn the body rotation axis is the
    gravity direction in the body frame and stays fixed, so the integrated rate is exactly
    ``angle * u`` (either sense), with ``u`` the unit gravity direction measured at rest next to
    the turn. Three turns about independent axes fix the gyro matrix on their own (see
    :func:`turn_init`); with gravity carrying they pin its scales about vertical axes.

    ``y_int`` (K, 3): ``sum y dt`` over the turn (midpoint rates; gyro units * s); ``dt_sum`` (K,):
    its duration; ``rest_acc`` (K, 3): mean accelerometer output at the adjacent rests;
    ``angle`` (K,): the magnitude of the turn (rad, ``2 pi`` per revolution); ``seg_ok`` (K,):
    False if the gyro saturated."""

    y_int: Float[Array, "K 3"]
    dt_sum: Float[Array, "K"]
    rest_acc: Float[Array, "K 3"]
    angle: Float[Array, "K"]
    seg_ok: Bool[Array, "K"]


def rests_around(spans: np.ndarray, n: int, gap: int, n_samples: int | None = None) -> list[list[tuple[int, int]]]:
    """Rest windows next to each span ``[a, b]``: ``n`` samples ending ``gap`` before ``a`` and ``n``
    samples starting ``gap`` after ``b`` (clipped to the recording's ``n_samples`` when given), as
    ``[start, stop)`` pairs."""
    end = np.iinfo(np.int64).max if n_samples is None else n_samples
    out = []
    for a, b in np.asarray(spans, np.int64).reshape(-1, 2):
        w = [(max(0, a - gap - n), max(0, a - gap)), (min(end, b + gap + 1), min(end, b + gap + 1 + n))]
        out.append([(int(x), int(y)) for x, y in w if y > x])
    return out


def prepare_turns(
    t: np.ndarray,
    acc: np.ndarray,
    gyr: np.ndarray,
    spans: np.ndarray,
    rests: list,
    *,
    revolutions: Any = 1,
    gyr_limit: float | None = None,
    midpoint: bool = True,
) -> VerticalTurns:
    """Vertical turns (numpy). ``spans`` (K, 2): first and last sample ``[a, b]`` of each turn;
    ``rests``: per turn, a list of static ``[start, stop)`` windows whose mean accelerometer output
    gives the turning axis (e.g. :func:`rests_around`); ``revolutions``: whole turns per section
    (scalar or (K,)). Raises if a turn has no rest samples."""
    t = np.asarray(t, np.float64)
    acc = np.asarray(acc, np.float64)
    gyr = np.asarray(gyr, np.float64)
    sp = [(int(a), int(b)) for a, b in np.asarray(spans).reshape(-1, 2)]
    if len(rests) != len(sp):
        raise ValueError(f"rests: need one list of windows per turn ({len(sp)}), got {len(rests)}")
    rest_acc = []
    for (a, b), win in zip(sp, rests):
        idx = np.concatenate([np.arange(x, y) for x, y in win]) if win else np.zeros(0, np.int64)
        if idx.size == 0:
            raise ValueError(f"turn [{a}, {b}]: no rest samples to take the turning axis from")
        rest_acc.append(acc[idx].mean(0))
    # the integrated rate sum(y dt) over a turn is the sum of its first-order block sums
    out, sdt, ok = _segment_sums(t, acc, gyr, sp, midpoint, 8, gyr_limit)
    angle = 2 * np.pi * np.broadcast_to(np.asarray(revolutions, np.float64), (len(sp),))
    return VerticalTurns(out["sy"].sum(1), sdt.sum(1), np.asarray(rest_acc), angle.copy(), ok)


class DatasheetPrior(NamedTuple):
    """Optional Gaussian prior (MAP) on the scales and cross-axis terms, from a datasheet.

    With a prior the fits weigh the data residuals by their std (``acc_sigma``: one pose's
    ``|f| - 1`` in g; ``gyr_sigma``: one component of a carried-gravity or known-rotation residual,
    rad) and add rows ``(M_ii - 1) / scale_sigma`` and ``M_ij / cross_sigma`` (i != j) for
    ``M = A / unit_per_lsb`` (relative to the nominal sensitivity). ``None`` for a sensor's
    ``*_unit_per_lsb`` leaves that sensor without prior. Off by default everywhere: multipos needs
    no datasheet; the prior only fills directions the poses do not observe.
    """

    acc_unit_per_lsb: float | None = None
    gyr_unit_per_lsb: float | None = None
    scale_sigma: float = 0.03
    cross_sigma: float = 0.02
    acc_sigma: float = 1e-3
    gyr_sigma: float = 0.01


#: InvenSense MPU-6050 (PS-MPU-6000A rev 3.4) at +-2 g / +-250 deg/s: 16384 LSB/g, 131 LSB/(deg/s),
#: sensitivity tolerance +-3 %, cross-axis sensitivity +-2 % (both sensors).
MPU6050_PRIOR = DatasheetPrior(acc_unit_per_lsb=1.0 / 16384.0, gyr_unit_per_lsb=float(np.pi / 180.0 / 131.0))


def prior_rows(a: Float[Array, "3 3"], unit_per_lsb: Any, prior: DatasheetPrior) -> Float[Array, "9"]:
    """Prior residuals of a calibration matrix ``A`` (unit/LSB): 3 scale rows, 6 cross-axis rows."""
    m = a / unit_per_lsb
    off = m[np.array([0, 0, 1, 1, 2, 2]), np.array([1, 2, 0, 2, 0, 1])]
    return jnp.concatenate([(jnp.diag(m) - 1.0) / prior.scale_sigma, off / prior.cross_sigma])


# ------------------------------------------------------------------------------ accelerometer


def _lower(a: Float[Array, "3"]) -> Float[Array, "3 3"]:
    z, o = jnp.zeros_like(a[0]), jnp.ones_like(a[0])
    return jnp.stack([jnp.stack([o, z, z]), jnp.stack([a[0], o, z]), jnp.stack([a[1], a[2], o])])


def _acc_matrix(theta: Float[Array, "P"], model: str) -> tuple[Array, Array]:
    """Normalised-frame ``(A', b')`` from the parameter vector."""
    if model == "9":
        return _lower(theta[:3]) * theta[3:6][None, :], theta[6:9]
    return theta[:9].reshape(3, 3), theta[9:12]


def acc_residuals(theta: Float[Array, "Q"], args: tuple) -> Float[Array, "P+3"]:
    """``sqrt(w_i) (|A'(m_i - b')| - 1)`` per pose (normalised pose means ``m_i``), plus the
    ``A - A^T`` gauge residual of the physical ``A = A' diag(1/s0)`` for the 12-parameter model (zeros for the 9-parameter one).
    With a :class:`DatasheetPrior` (``args[4]``, optional) the pose rows are divided by its
    ``acc_sigma`` and its 9 prior rows on the physical ``A`` are appended. ``args[5]`` (optional,
    default 0): ridge weight on the cross-axis terms of ``A'`` (relative to its diagonal), 6 rows
    ``ridge * A'_ij / A'_jj`` (i != j; the 9-parameter model's three zeros above the diagonal stay 0)."""
    m, w, model, s0 = args[:4]
    prior = args[4] if len(args) > 4 else None
    ridge = args[5] if len(args) > 5 else 0.0
    a, b = _acc_matrix(theta, model)
    f = (m - b) @ a.T
    r = jnp.sqrt(w) * (jnp.linalg.norm(f, axis=-1) - 1.0)
    ap = a * (jnp.mean(s0) / s0)[None, :]  # the physical A, up to one common factor
    gauge = jnp.stack([ap[0, 1] - ap[1, 0], ap[0, 2] - ap[2, 0], ap[1, 2] - ap[2, 1]]) if model == "12" else jnp.zeros(3, m.dtype)
    rel = a / jnp.diag(a)[None, :]
    r = jnp.concatenate([r, ridge * rel[np.array([0, 0, 1, 1, 2, 2]), np.array([1, 2, 0, 2, 0, 1])]])
    if prior is None or prior.acc_unit_per_lsb is None:
        return jnp.concatenate([r, gauge])
    return jnp.concatenate([r / prior.acc_sigma, gauge, prior_rows(a / s0[None, :], prior.acc_unit_per_lsb, prior)])


def ellipsoid_init(m: Float[Array, "P 3"], w: Float[Array, "P"]) -> tuple[Array, Array]:
    """Centre and semi-axes of the axis-aligned ellipsoid through weighted points (least squares
    on ``a x^2 + b y^2 + c z^2 + d x + e y + f z = 1``); per-axis (max + min) / 2 and (max - min) / 2
    where that fit is degenerate."""
    mu = jnp.sum(w[:, None] * m, 0) / jnp.sum(w)
    sd = jnp.sqrt(jnp.sum(w[:, None] * (m - mu) ** 2, 0) / jnp.sum(w)) + 1e-12
    x = (m - mu) / sd
    d = jnp.concatenate([x * x, x], axis=1) * jnp.sqrt(w)[:, None]
    coef, *_ = jnp.linalg.lstsq(d, jnp.sqrt(w), rcond=None)
    q, l = coef[:3], coef[3:]
    ok = jnp.all(q > 0)
    qs = jnp.where(ok, q, 1.0)
    c = -l / (2 * qs)
    rhs = 1.0 + jnp.sum(l * l / (4 * qs))
    r = jnp.sqrt(jnp.maximum(rhs / qs, 1e-24))
    big = jnp.where(w[:, None] > 0, m, -jnp.inf).max(0)
    small = jnp.where(w[:, None] > 0, m, jnp.inf).min(0)
    c_mm, r_mm = 0.5 * (big + small), jnp.maximum(0.5 * (big - small), 1e-12)
    ok = ok & jnp.all(jnp.isfinite(r)) & jnp.all(r * sd > 0.2 * r_mm)
    return jnp.where(ok, mu + c * sd, c_mm), jnp.where(ok, r * sd, r_mm)


def fit_acc(
    pose_acc: Float[Array, "P 3"], w: Float[Array, "P"], model: str = "9", max_steps: int = 100,
    prior: DatasheetPrior | None = None, ridge: float = 1e-2,
) -> tuple[InverseAffine, Array]:
    """Accelerometer multi-position fit (weights ``w`` per pose; 0 leaves a pose out; optional
    datasheet ``prior``, MAP). The returned cost leaves the prior and ridge rows out and is
    unweighted.

    ``ridge`` (default 1e-2 g per unit of cross-axis term) keeps the non-orthogonality terms that
    the poses barely see at zero instead of fitting them to noise: with poses along the sensor
    axes only (a six-face protocol, and its repeats) they are unobserved to first order and a free
    fit wanders to ~0.1; with poses in general directions the ridge moves nothing measurable."""
    c0, s0 = ellipsoid_init(pose_acc, w)
    m = (pose_acc - c0) / s0
    if model == "9":
        theta0 = jnp.concatenate([jnp.zeros(3), jnp.ones(3), jnp.zeros(3)]).astype(m.dtype)
    elif model == "12":
        theta0 = jnp.concatenate([jnp.eye(3).ravel(), jnp.zeros(3)]).astype(m.dtype)
    else:
        raise ValueError(f"acc_model must be '9' or '12', got {model!r}")
    solver = optx.LevenbergMarquardt(rtol=1e-10, atol=1e-12)
    sol = optx.least_squares(acc_residuals, solver, theta0, args=(m, w, model, s0, prior, ridge), max_steps=max_steps, throw=False)
    a, b = _acc_matrix(sol.value, model)
    cost = jnp.sum(acc_residuals(sol.value, (m, w, model, s0)) ** 2)
    return InverseAffine(A=a / s0[None, :], b=c0 + s0 * b), cost


#: relative singular value below which a parameter combination counts as undetermined by the poses
OBSERVABLE_TOL = 0.02


def fit_acc_determined(
    pose_acc: Float[Array, "P 3"], w: Float[Array, "P"], tol: float = OBSERVABLE_TOL, steps: int = 20
) -> tuple[InverseAffine, Array]:
    """Accelerometer fit for poses that do not determine every parameter: start from the
    recording's own units (``A = I``, ``b = 0``; the recording must already be in g) and take
    Gauss-Newton steps on the 9-parameter model (``A = L diag(s)``, ``L`` unit lower triangular)
    restricted to the combinations whose relative singular value in the weighted Jacobian of
    ``|A (m_i - b)| - 1`` exceeds ``tol`` (truncated SVD). The others stay as recorded: the
    minimum-norm correction the data support. Returns the calibration and the number of
    combinations moved (of 9)."""
    w = jnp.sqrt(w)

    def res(th):
        a = _lower(th[:3]) * th[3:6][None, :]
        return w * (jnp.linalg.norm((pose_acc - th[6:9]) @ a.T, axis=-1) - 1.0)

    def step(_, carry):
        th, _ = carry
        u, sv, vt = jnp.linalg.svd(jax.jacfwd(res)(th), full_matrices=False)
        keep = sv > tol * sv[0]
        inv = jnp.where(keep, 1.0 / jnp.where(keep, sv, 1.0), 0.0)
        return th - vt.T @ (inv * (u.T @ res(th))), jnp.sum(keep)

    th0 = jnp.concatenate([jnp.zeros(3), jnp.ones(3), jnp.zeros(3)]).astype(pose_acc.dtype)
    th, n = jax.lax.fori_loop(0, steps, step, (th0, jnp.asarray(0)))
    return InverseAffine(_lower(th[:3]) * th[3:6][None, :], th[6:9]), n


# ------------------------------------------------------------------------------ gyroscope


def carry_rotation(w: Float[Array, "J L 3"], dt: Float[Array, "J L"]) -> Float[Array, "J 3 3"]:
    """``R_j = prod_l Exp(w_jl dt_jl)`` (ordered, left to right) for every transition.

    Padding steps have ``dt = 0`` (identity). The product is a pairwise tree reduction
    (``log2 L`` batched matrix products) rather than an ``L``-step scan: same result, far fewer
    sequential steps.
    """
    L = w.shape[1]
    n = 1 << max(0, int(np.ceil(np.log2(max(L, 1)))))
    r = exp_so3(w * dt[..., None])
    if n > L:
        eye = jnp.broadcast_to(jnp.eye(3, dtype=r.dtype), (r.shape[0], n - L, 3, 3))
        r = jnp.concatenate([r, eye], axis=1)
    while r.shape[1] > 1:
        r = r[:, 0::2] @ r[:, 1::2]
    return r[:, 0]


def cofactor(g: Float[Array, "3 3"]) -> Float[Array, "3 3"]:
    """Cofactor matrix, ``(G u) x (G v) = cof(G) (u x v)`` for every ``u, v``."""
    return jnp.stack([jnp.cross(g[:, 1], g[:, 2]), jnp.cross(g[:, 2], g[:, 0]), jnp.cross(g[:, 0], g[:, 1])], axis=1)


def block_rotvecs(
    g: Float[Array, "3 3"], b: Float[Array, "3"], gsens: Float[Array, "3 3"], d: MultiposData, seg_f_off: Float[Array, "J L 3"]
) -> Float[Array, "J L 3"]:
    """Rotation vector of every block for ``w = G (y - b) - G_s f`` (second-order Magnus; the
    g-sensitivity term enters to first order, ``seg_f_off`` = block sums of calibrated ``f dt``)."""
    first = (d.sy - b * d.sdt[..., None]) @ g.T
    cross = d.c0 - jnp.cross(b, d.p1) + jnp.cross(b, d.p2)
    return first + 0.5 * cross @ cofactor(g).T - seg_f_off @ gsens.T


def _calibrated_acc_sums(acc: InverseAffine, d: MultiposData) -> Float[Array, "J L 3"]:
    return (d.sacc - acc.b * d.sdt[..., None]) @ acc.A.T


def known_rotation_residuals(
    g: Float[Array, "3 3"], b: Float[Array, "3"], gsens: Float[Array, "3 3"], known: KnownRotations, fsum: Float[Array, "K L 3"]
) -> Float[Array, "K 3"]:
    """``log_so3(R_known^T R_int)`` per known-rotation section (rad, 3 components; physical
    convention, ``R_int = prod Exp(w dt)`` of ``w = G (y - b) - G_s f``). Pure and vmappable."""
    r = carry_rotation(block_rotvecs(g, b, gsens, known, fsum), jnp.ones_like(known.sdt))
    return log_so3(jnp.swapaxes(known.R, -1, -2) @ r)


def _turn_axes(acc: InverseAffine, turns: VerticalTurns) -> Float[Array, "K 3"]:
    f = (turns.rest_acc - acc.b) @ acc.A.T
    return f / jnp.linalg.norm(f, axis=-1, keepdims=True)


def vertical_turn_residuals(
    g: Float[Array, "3 3"], b: Float[Array, "3"], gsens: Float[Array, "3 3"], acc: InverseAffine, turns: VerticalTurns
) -> Float[Array, "K 3"]:
    """``I_k - angle_k s_k u_k`` per turn (rad): ``I_k = G (y_int - b dt) - G_s f dt`` the
    integrated calibrated rate, ``u_k`` the calibrated gravity direction at the adjacent rests,
    ``s_k = sign(I_k . u_k)`` the sense of the turn. Zero for an exact turn about the vertical."""
    u = _turn_axes(acc, turns)
    i = (turns.y_int - b * turns.dt_sum[:, None]) @ g.T - (u * turns.dt_sum[:, None]) @ gsens.T
    s = jnp.sign(jnp.sum(i * u, -1))
    return i - (turns.angle * s)[:, None] * u


def vertical_turn_errors(
    gyr: InverseAffine, gsens: Float[Array, "3 3"], acc: InverseAffine, turns: VerticalTurns
) -> Float[Array, "K"]:
    """Norm of :func:`vertical_turn_residuals` per turn (rad): the angle by which the integrated
    turn misses a whole turn about the measured vertical."""
    return jnp.linalg.norm(vertical_turn_residuals(gyr.A, gyr.b, gsens, acc, turns), axis=-1)


def turn_init(b: Float[Array, "3"], acc: InverseAffine, turns: VerticalTurns, w: Float[Array, "K"], sign: Any = 1.0) -> Float[Array, "3 3"]:
    """Closed-form gyro matrix from vertical turns (weights ``w``; at least three about independent
    axes): least squares ``G Y = U`` with ``Y_k = y_int_k - b dt_k`` and ``U_k = angle_k s_k u_k``,
    where the sense ``s_k = sign(sign * Y_k . u_k)`` follows a guess of ``sign(G)`` (``sign``). This
    is the Ferraris gyro calibration with the axes measured by the accelerometer instead of labelled."""
    u = _turn_axes(acc, turns)
    y = turns.y_int - b * turns.dt_sum[:, None]
    s = jnp.sign(sign * jnp.sum(y * u, -1))
    target = (turns.angle * s)[:, None] * u
    yw = y * w[:, None]
    # weighted normal equations of min sum_k w_k |G y_k - target_k|^2: (Y^T W Y) G^T = Y^T W T
    return jnp.linalg.lstsq(yw.T @ y, yw.T @ target, rcond=1e-10)[0].T


def gyr_residuals(theta: Float[Array, "Q"], args: tuple) -> Float[Array, "R"]:
    """``sqrt(w_j) (R_j^T u_j - u_{j+1})`` for every transition ``j`` (physical convention).

    Optional ``args[7:]``: ``(known, known_w, known_fsum, prior, turns, turns_w, acc)``:
    known-rotation rows ``sqrt(w_k) log_so3(R_known^T R_int)`` (:func:`known_rotation_residuals`),
    vertical-turn rows ``sqrt(w_k) (I_k - angle_k s_k u_k)`` (:func:`vertical_turn_residuals`, axes
    from the accelerometer calibration ``acc``) and, with a :class:`DatasheetPrior`, all data rows
    divided by its ``gyr_sigma`` plus its 9 prior rows on ``G``."""
    d, bg, s0, gs, fsum, u, wj = args[:7]
    known, known_w, kfsum, prior = args[7:11] if len(args) > 7 else (None, None, None, None)
    turns, turns_w, acc = args[11:14] if len(args) > 11 else (None, None, None)
    g = s0 * (jnp.eye(3, dtype=theta.dtype) + theta[:9].reshape(3, 3))
    gsm = theta[9:18].reshape(3, 3) if gs else jnp.zeros((3, 3), theta.dtype)
    r = carry_rotation(block_rotvecs(g, bg, gsm, d, fsum), jnp.ones_like(d.sdt))
    pred = jnp.einsum("jba,jb->ja", r, u[:-1])  # R^T u_j
    rows = [(jnp.sqrt(wj)[:, None] * (pred - u[1:])).ravel()]
    if known is not None:
        kr = known_rotation_residuals(g, bg, gsm, known, kfsum)
        rows.append((jnp.sqrt(known_w * known.seg_ok.astype(kr.dtype))[:, None] * kr).ravel())
    if turns is not None:
        tr = vertical_turn_residuals(g, bg, gsm, acc, turns)
        rows.append((jnp.sqrt(turns_w * turns.seg_ok.astype(tr.dtype))[:, None] * tr).ravel())
    if prior is not None and prior.gyr_unit_per_lsb is not None:
        rows = [x / prior.gyr_sigma for x in rows] + [prior_rows(g, prior.gyr_unit_per_lsb, prior)]
    return jnp.concatenate(rows)


def gyro_angle_errors(
    gyr: InverseAffine, gsens: Float[Array, "3 3"], acc: InverseAffine, data: MultiposData
) -> Float[Array, "J"]:
    """Angle (rad) between the gyro-carried gravity direction of pose ``j`` and pose ``j + 1``'s."""
    f = (data.pose_acc - acc.b) @ acc.A.T
    u = f / jnp.linalg.norm(f, axis=-1, keepdims=True)
    rv = block_rotvecs(gyr.A, gyr.b, gsens, data, _calibrated_acc_sums(acc, data))
    r = carry_rotation(rv, jnp.ones_like(data.sdt))
    pred = jnp.einsum("jba,jb->ja", r, u[:-1])
    c = jnp.sum(pred * u[1:], -1) / jnp.linalg.norm(pred, axis=-1)
    return jnp.arccos(jnp.clip(c, -1.0, 1.0))


def known_rotation_errors(
    gyr: InverseAffine, gsens: Float[Array, "3 3"], acc: InverseAffine, known: KnownRotations
) -> Float[Array, "K"]:
    """Angle (rad) of ``R_known^T R_int`` per known-rotation section: the rotation error."""
    kr = known_rotation_residuals(gyr.A, gyr.b, gsens, known, _calibrated_acc_sums(acc, known))
    return jnp.linalg.norm(kr, axis=-1)


def acc_norm_errors(acc: InverseAffine, pose_acc: Float[Array, "P 3"]) -> Float[Array, "P"]:
    """``| |f_i| - 1 |`` per pose (g) for calibrated pose means."""
    return jnp.abs(jnp.linalg.norm((pose_acc - acc.b) @ acc.A.T, axis=-1) - 1.0)


def fit_prepared(
    data: MultiposData,
    config: MultiposConfig = MultiposConfig(),
    acc_w: Float[Array, "P"] | None = None,
    gyr_w: Float[Array, "J"] | None = None,
    known: KnownRotations | None = None,
    known_w: Float[Array, "K"] | None = None,
    turns: VerticalTurns | None = None,
    turns_w: Float[Array, "T"] | None = None,
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
    """
    P = data.pose_acc.shape[0]
    dtype = data.pose_acc.dtype
    if config.acc_fit not in ("full", "determined") or config.gyr_fit not in ("full", "none"):
        raise ValueError(f"acc_fit must be 'full' or 'determined' and gyr_fit 'full' or 'none', got "
                         f"{config.acc_fit!r} and {config.gyr_fit!r}")
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
        return MultiposFit(acc, InverseAffine(jnp.eye(3, dtype=dtype), jnp.zeros(3, dtype)), zero, acc_cost, jnp.asarray(0.0, dtype))
    f = (data.pose_acc - acc.b) @ acc.A.T
    u = f / jnp.linalg.norm(f, axis=-1, keepdims=True)
    # gyro bias from the static intervals (of the poses in use)
    if config.gyro_bias == "init":
        bg = data.pose_gyr[0]
    else:
        wn = acc_w * data.pose_n
        bg = jnp.sum(wn[:, None] * data.pose_gyr, 0) / jnp.sum(wn)
    fsum = _calibrated_acc_sums(acc, data)
    if known is not None:
        known_w = jnp.ones(known.R.shape[0], dtype) if known_w is None else known_w
        kfsum = _calibrated_acc_sums(acc, known)
        extra = (known, known_w, kfsum)
    else:
        extra = (None, None, None)
    if turns is not None:
        turns_w = jnp.ones(turns.angle.shape[0], dtype) if turns_w is None else turns_w
        textra = (turns, turns_w, acc)
    else:
        textra = (None, None, None)
    # scale initialisation: grid over G = s I, both signs (4 per decade)
    grid = jnp.concatenate([jnp.logspace(-7, 1, 33), -jnp.logspace(-7, 1, 33)]).astype(dtype)
    zero = jnp.zeros(18 if config.g_sensitivity else 9, dtype)

    def cost_at(s, th):
        return jnp.sum(gyr_residuals(th, (data, bg, s, config.g_sensitivity, fsum, u, gyr_w, *extra, None, *textra)) ** 2)

    costs = jnp.nan_to_num(jax.vmap(lambda s: cost_at(s, zero))(grid), nan=jnp.inf)
    s0 = grid[jnp.argmin(costs)]
    theta0 = zero
    if turns is not None and turns.angle.shape[0] >= 3:  # label-free Ferraris start, if it is better
        gc = turn_init(bg, acc, turns, turns_w * turns.seg_ok.astype(dtype), jnp.sign(s0))
        th_c = zero.at[:9].set((gc / s0 - jnp.eye(3, dtype=dtype)).ravel())
        c_c = jnp.nan_to_num(cost_at(s0, th_c), nan=jnp.inf)
        theta0 = jnp.where(c_c < jnp.min(costs), th_c, zero)
    args = (data, bg, s0, config.g_sensitivity, fsum, u, gyr_w, *extra, config.prior, *textra)
    solver = optx.LevenbergMarquardt(rtol=1e-9, atol=1e-12)
    sol = optx.least_squares(gyr_residuals, solver, theta0, args=args, max_steps=config.max_steps, throw=False)
    g = s0 * (jnp.eye(3, dtype=dtype) + sol.value[:9].reshape(3, 3))
    gs = sol.value[9:18].reshape(3, 3) if config.g_sensitivity else jnp.zeros((3, 3), dtype)
    gyr_cost = jnp.sum(gyr_residuals(sol.value, args[:10] + (None,) + args[11:]) ** 2)
    return MultiposFit(acc, InverseAffine(g, bg), gs, acc_cost, gyr_cost)


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
    :func:`prepare_turns`); returns numpy-backed arrays."""
    return _fit_numpy(prepare(t, acc, gyr, intervals, gyr_limit=gyr_limit, midpoint=config.midpoint, block=block), config, turns)


def _fit_numpy(data: MultiposData, config: MultiposConfig, turns: VerticalTurns | None) -> MultiposFit:
    """:func:`fit_prepared` (jitted, float64) on numpy-prepared data; numpy-backed result."""
    with jax.enable_x64(True):
        d = jax.tree_util.tree_map(jnp.asarray, data)
        tv = None if turns is None else jax.tree_util.tree_map(jnp.asarray, turns)
        fit = jax.jit(fit_prepared, static_argnums=1)(d, config, None, None, None, None, tv)
        return jax.tree_util.tree_map(np.asarray, fit)


class Observability(NamedTuple):
    """What the poses determine, at a fit (numpy). ``acc_sv`` (6,): singular values, relative to the
    largest, of the accelerometer's first-order design ``[u * u, u]`` (rows: the calibrated
    gravity direction ``u`` of each pose in use; columns: the three scales and three biases that
    ``| |f| - 1 |`` sees; the cross-axis terms are held by the ridge). ``gyr_sv`` (9,): the same for
    the gyro matrix ``G``, from the first-order rows ``[u_{j+1}]_x (Y_j^T kron I)`` of every usable
    transition (``Y_j`` its integrated calibrated rate; the gravity direction is blind to the
    rotation about itself) and ``Y_k^T kron I`` of every vertical turn. ``spread_deg``: largest
    angle between a pose's raw (uncalibrated) output direction and their mean."""

    acc_sv: np.ndarray
    gyr_sv: np.ndarray
    spread_deg: float


def observability(data: MultiposData, fit: MultiposFit, acc_w: np.ndarray | None = None, gyr_w: np.ndarray | None = None,
                  turns: VerticalTurns | None = None) -> Observability:
    """:class:`Observability` of ``fit`` on ``data`` (weights as in :func:`fit_prepared`; a zero
    leaves a pose or transition out). A relative singular value near 0 is a parameter combination
    the recording does not determine: the fit put it wherever the start or the ridge left it."""
    a, b = np.asarray(fit.acc.A), np.asarray(fit.acc.b)
    g, bg = np.asarray(fit.gyr.A), np.asarray(fit.gyr.b)
    P = len(data.pose_acc)
    aw = np.ones(P) if acc_w is None else np.asarray(acc_w)
    gw = (np.ones(P - 1) if gyr_w is None else np.asarray(gyr_w)) * np.asarray(data.seg_ok)
    f = (np.asarray(data.pose_acc) - b) @ a.T
    u = f / np.linalg.norm(f, axis=1, keepdims=True)
    ua = u[aw > 0]
    acc_sv = np.linalg.svd(np.concatenate([ua * ua, ua], 1), compute_uv=False)
    raw = np.asarray(data.pose_acc)[aw > 0]  # as the sensor reads them: a bad fit cannot spread them
    raw = raw / np.linalg.norm(raw, axis=1, keepdims=True)
    mean = raw.mean(0) / max(np.linalg.norm(raw.mean(0)), 1e-12)
    spread = float(np.degrees(np.arccos(np.clip(raw @ mean, -1.0, 1.0))).max())
    rows = [np.zeros((1, 9))]
    sy, sdt = np.asarray(data.sy).sum(1), np.asarray(data.sdt).sum(1)
    with jax.enable_x64(True):
        u_next = np.asarray(hat(jnp.asarray(u[1:])))
    for j in np.flatnonzero(gw > 0):
        y = (sy[j] - bg * sdt[j]) @ g.T
        rows.append(u_next[j] @ np.kron(y[None, :], np.eye(3)))
    if turns is not None:
        for k in np.flatnonzero(np.asarray(turns.seg_ok)):
            y = (np.asarray(turns.y_int[k]) - bg * float(turns.dt_sum[k])) @ g.T
            rows.append(np.kron(y[None, :], np.eye(3)))
    gyr_sv = np.linalg.svd(np.concatenate(rows), compute_uv=False)
    rel = lambda x: x / x[0] if x[0] > 0 else x  # noqa: E731
    return Observability(rel(acc_sv), rel(gyr_sv), spread)


def check_observable(obs: Observability, tol: float = OBSERVABLE_TOL) -> None:
    """Raise ``ValueError`` (saying what is missing and what to record) when a relative singular
    value of :class:`Observability` is below ``tol``: a calibration with undetermined parameters
    would be written as if it were one."""
    msgs = []
    n_acc = int((obs.acc_sv < tol).sum())
    if n_acc:
        msgs.append(f"the static poses leave {n_acc} of the accelerometer's 6 scale/bias combinations undetermined "
                    f"(relative singular values {np.array2string(obs.acc_sv, precision=3)}; their raw directions lie "
                    f"within {obs.spread_deg:.1f} deg of their mean): hold the IMU still in at least six directions, "
                    "e.g. on each of its six faces")
    n_gyr = int((obs.gyr_sv < tol).sum())
    if n_gyr:
        msgs.append(f"the rotations between the poses leave {n_gyr} of the gyro matrix's 9 combinations undetermined "
                    f"(relative singular values {np.array2string(obs.gyr_sv, precision=3)}): turn the IMU about each of "
                    "its axes between poses, or add whole turns about the vertical (--turns)")
    if msgs:
        raise ValueError(f"cannot calibrate this recording: {'; '.join(msgs)} (tolerance {tol})")


def turns_from_times(t: np.ndarray, acc: np.ndarray, gyr: np.ndarray, times: Any, rest: float = 1.0,
                     gyr_limit: float | None = None) -> VerticalTurns:
    """:class:`VerticalTurns` from turn start/end times ``times`` (K, 2) in seconds; each turn's axis
    is read from ``rest`` seconds of rest just before and just after it (5 samples away)."""
    t = np.asarray(t, np.float64)
    tt = np.asarray(times, np.float64).reshape(-1, 2)
    if np.any(tt[:, 1] <= tt[:, 0]) or tt.min() < t[0] or tt.max() > t[-1]:
        raise ValueError(f"turns: each needs start < end inside the recording [{t[0]:.3f}, {t[-1]:.3f}] s, got {tt.tolist()}")
    spans = np.stack([np.searchsorted(t, tt[:, 0]), np.minimum(np.searchsorted(t, tt[:, 1]), len(t) - 1)], 1)
    n = max(1, int(round(rest / float(np.median(np.diff(t))))))
    return prepare_turns(t, acc, gyr, spans, rests_around(spans, n, 5, len(t)), gyr_limit=gyr_limit)


def to_affine(cal: InverseAffine) -> Affine:
    """The forward model ``y = S x + b`` (``S = A^-1``) of an applied calibration."""
    return Affine(S=np.linalg.inv(np.asarray(cal.A)), b=np.asarray(cal.b))


def default_gyr_limit(gyr: np.ndarray, unit: str) -> float | None:
    """Saturation limit for raw counts: 32767 for signed, 65535 for unsigned 16-bit data."""
    if unit != "LSB":
        return None
    return 32767.0 if np.min(gyr) < 0 else 65535.0


def detect_and_fit(
    t: np.ndarray,
    acc: np.ndarray,
    gyr: np.ndarray,
    config: MultiposConfig = MultiposConfig(),
    *,
    init_duration: float | None = None,
    ks: tuple[float, ...] = tuple(range(1, 11)),
    window: float = 1.0,
    min_duration: float = 1.0,
    gyr_limit: float | None = None,
    turn_times: Any = None,
    gyr_gate: bool = False,
    check: bool = True,
) -> tuple[MultiposFit, np.ndarray, float]:
    """imu_tk's procedure: for each threshold multiplier ``k`` detect the static intervals and
    fit the accelerometer; keep the ``k`` with the smallest mean squared ``|f| - 1`` residual
    (at least 9 poses), then fit the gyroscope. Returns ``(fit, intervals, k)``. ``turn_times``
    (K, 2) s, optional: whole turns about the vertical (:func:`turns_from_times`), unlabelled.
    ``gyr_gate``: also require a quiet gyro at rest (:func:`~jaxcal.static.detect_static`), which
    keeps turns about the vertical out of the poses; off by default (imu_tk's detector).
    ``check``: raise ``ValueError`` when the poses do not determine the fit (:func:`check_observable`).

    ``init_duration`` defaults to the first run of low acceleration variance: the first 10 % of
    the recording, capped at 30 s, is a safe guess only if the user rested there; pass it.
    """
    fit, det, data, turns = _detect_fit(t, acc, gyr, config, init_duration, ks, window, min_duration, gyr_limit, turn_times, gyr_gate)
    if check:
        check_observable(observability(data, fit, turns=turns))
    return fit, det.intervals, det.k


def _detect_fit(t, acc, gyr, config, init_duration, ks, window, min_duration, gyr_limit, turn_times, gyr_gate):
    """:func:`detect_and_fit`'s work: ``(fit, detection, prepared data, turns)``."""
    t = np.asarray(t, np.float64)
    if init_duration is None:
        init_duration = min(30.0, 0.1 * (t[-1] - t[0]))
    best = None
    for k in ks:
        det = detect_static(t, acc, k=k, init_duration=init_duration, window=window, min_duration=min_duration,
                            gyr=gyr if gyr_gate else None)
        if len(det.intervals) < 9:
            continue
        with jax.enable_x64(True):
            pa = jnp.asarray(np.stack([np.asarray(acc, np.float64)[a:b].mean(0) for a, b in det.intervals]))
            _, cost = jax.jit(fit_acc, static_argnums=(2, 3))(pa, jnp.ones(len(pa)), config.acc_model, config.max_steps, None, config.acc_ridge)
        score = float(cost) / len(pa)
        if best is None or score < best[0]:
            best = (score, det)
    if best is None:
        raise ValueError("fewer than 9 static poses found for every threshold; record more poses")
    det = best[1]
    turns = None if turn_times is None else turns_from_times(t, acc, gyr, turn_times, gyr_limit=gyr_limit)
    data = prepare(t, acc, gyr, det.intervals, gyr_limit=gyr_limit, midpoint=config.midpoint)
    return _fit_numpy(data, config, turns), det, data, turns


def fit_summary(data: MultiposData, fit: MultiposFit, turns: VerticalTurns | None = None,
                obs: Observability | None = None) -> dict:
    """In-sample quality of a fit on its own poses, for the user to judge a calibration: pose and
    usable-transition counts, RMS ``| |f| - 1 |`` (mg), median carried-gravity angle (deg), the
    worst vertical-turn error (deg, with ``turns``), and the smallest relative singular values of
    :func:`observability` (near 0: a combination the poses barely determine). In-sample figures
    are optimistic; ``leave_poses_out`` gives held-out ones. ``obs``: :func:`observability` of the
    same fit, if already computed."""
    with jax.enable_x64(True):
        d = jax.tree_util.tree_map(jnp.asarray, data)
        ea = np.asarray(acc_norm_errors(fit.acc, d.pose_acc))
        eg = np.asarray(gyro_angle_errors(fit.gyr, fit.gsens, fit.acc, d))[np.asarray(data.seg_ok)]
        et = None if turns is None else np.asarray(vertical_turn_errors(
            fit.gyr, fit.gsens, fit.acc, jax.tree_util.tree_map(jnp.asarray, turns)))
    obs = observability(data, fit, turns=turns) if obs is None else obs
    out = {"n_poses": int(len(ea)), "n_transitions": int(len(eg)), "acc_rms_mg": float(1e3 * np.sqrt(np.mean(ea**2))),
           "gyr_median_deg": float(np.degrees(np.median(eg))) if len(eg) else None,
           "acc_sv_min": float(obs.acc_sv.min()), "gyr_sv_min": float(obs.gyr_sv.min())}
    if et is not None:
        out["turn_max_deg"] = float(np.degrees(et.max()))
    return out


def fit_multipos_recording(rec: Any, config: MultiposConfig = MultiposConfig(), *, summary: bool = False,
                           partial: bool = False, **kwargs) -> tuple[Any, Any] | tuple[Any, Any, dict]:
    """Calibrate a :class:`~jaxcal.recording.Recording` (or recording dict) by multi-position
    self-calibration. Needs ``acc`` and ``gyr``; no labels, no datasheet values.

    Returns the forward models ``(acc_model, gyr_model)`` as :class:`~jaxcal.sensor.Affine`
    (``y = S x + b``, ``x`` in g and rad/s, ``y`` in the recording's units). The g-sensitivity
    option is not representable as an ``Affine`` and is off here. ``kwargs`` go to
    :func:`detect_and_fit` (here ``gyr_gate`` defaults to True; ``turn_times`` adds vertical turns).
    ``summary``: also return :func:`fit_summary` of the fit (in-sample quality, observability).

    When the poses do not determine every combination (:func:`check_observable`) this raises,
    unless ``partial``: then, for a recording already in g and rad/s, the accelerometer is fitted
    by :func:`fit_acc_determined` (only the determined combinations move) and an undetermined
    gyroscope is left as recorded (its model is ``None``); the summary's ``partial`` says which.
    """
    get = (lambda k: rec.get(k)) if isinstance(rec, dict) else (lambda k: getattr(rec, k, None))
    t, acc, gyr = get("t"), get("acc"), get("gyr")
    if acc is None or gyr is None:
        raise ValueError("multipos needs both 'acc' and 'gyr'")
    if config.g_sensitivity:
        raise ValueError("fit_multipos_recording returns affine models; use fit_multipos for g-sensitivity")
    units = (get("acc_unit") or "LSB", get("gyr_unit") or "LSB")
    if partial and units != ("g", "rad/s"):
        raise ValueError(f"partial keeps what the poses do not determine as recorded, which needs a recording in "
                         f"g and rad/s; this one is in {units[0]} and {units[1]}")
    kwargs.setdefault("gyr_limit", default_gyr_limit(np.asarray(gyr), units[1]))
    kwargs.setdefault("gyr_gate", True)  # a turn about the vertical must not pass for a pose
    check = kwargs.pop("check", True)
    defaults = {k: v for k, v in detect_and_fit.__kwdefaults__.items() if k != "check"}
    fit, _, data, turns = _detect_fit(t, acc, gyr, config, **(defaults | kwargs))
    obs = observability(data, fit, turns=turns) if check or summary or partial else None
    kept = {}
    if partial:
        if (obs.acc_sv < OBSERVABLE_TOL).any():
            config = config._replace(acc_fit="determined")
            with jax.enable_x64(True):
                n = int(fit_acc_determined(jnp.asarray(data.pose_acc, jnp.float64), jnp.ones(len(data.pose_acc)))[1])
            kept["acc"] = f"{9 - n} of 9 combinations left as recorded, {n} fitted"
            fit = _fit_numpy(data, config, turns)
            obs = observability(data, fit, turns=turns)  # the gyro design, linearised at the new gravity directions
        if (obs.gyr_sv < OBSERVABLE_TOL).any():
            config = config._replace(gyr_fit="none")
            kept["gyr"] = "left as recorded (the rotations determine too little)"
            fit = _fit_numpy(data, config, turns)
    elif check:
        try:
            check_observable(obs)
        except ValueError as e:
            raise ValueError(f"{e}; or calibrate only what the poses determine (partial=True, --partial)") from None
    models = (to_affine(fit.acc), None if config.gyr_fit == "none" else to_affine(fit.gyr))
    if not summary:
        return models
    return (*models, fit_summary(data, fit, turns, obs) | ({"partial": kept} if kept else {}))


class HeldOut(NamedTuple):
    """Leave-poses-out scores: ``acc_err`` (P,) ``| |f| - 1 |`` in g of each pose from the fold
    that left it out, ``gyr_err`` (J,) the carried-gravity angle (rad) of each transition from
    the fold that left it out (NaN for unusable transitions), and the fold of each."""

    acc_err: np.ndarray
    gyr_err: np.ndarray
    pose_fold: np.ndarray
    trans_fold: np.ndarray


def fold_ids(n: int, n_folds: int) -> np.ndarray:
    """Interleaved folds: item ``i`` goes to fold ``i mod n_folds``."""
    return np.arange(n) % n_folds


def leave_poses_out(
    data: MultiposData, config: MultiposConfig = MultiposConfig(), n_folds: int | None = None
) -> HeldOut:
    """Held-out scores with interleaved folds over poses (and transitions), all folds fitted in
    one ``vmap`` of :func:`fit_prepared`. ``n_folds=None`` leaves one pose (and one transition)
    out at a time. Fold ``k`` leaves out poses ``i = k mod n_folds`` from the accelerometer fit and
    transitions ``j = k mod n_folds`` from the gyroscope fit, then scores exactly those.
    """
    P = data.pose_acc.shape[0]
    F = P if n_folds is None else n_folds
    pf, tf = fold_ids(P, F), fold_ids(P - 1, F)
    with jax.enable_x64(True):
        d = jax.tree_util.tree_map(jnp.asarray, data)
        aw = jnp.asarray((pf[None, :] != np.arange(F)[:, None]).astype(np.float64))
        gw = jnp.asarray((tf[None, :] != np.arange(F)[:, None]).astype(np.float64))

        @jax.jit
        def run(aw, gw):
            fits = jax.vmap(lambda a, g: fit_prepared(d, config, a, g))(aw, gw)
            ea = jax.vmap(lambda f: acc_norm_errors(f.acc, d.pose_acc))(fits)
            eg = jax.vmap(lambda f: gyro_angle_errors(f.gyr, f.gsens, f.acc, d))(fits)
            return ea, eg

        ea, eg = (np.asarray(x) for x in run(aw, gw))
    acc_err = ea[pf, np.arange(P)]
    gyr_err = np.where(np.asarray(data.seg_ok), eg[tf, np.arange(P - 1)], np.nan)
    return HeldOut(acc_err, gyr_err, pf, tf)
