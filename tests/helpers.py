"""Shared test helpers: an analytic rig (attitude and position as sums of sines, so body rate and
specific force are closed form) with the IMU at the reference point in the reference frame
(tau = 0, R_ref_imu = I, r = 0). Rotations use scipy.spatial.transform.Rotation, not jaxcal code.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from scipy.spatial.transform import Rotation

from jaxcal.recording import Recording, recording_from_dict

G0 = 9.80665
FS = 200.0
T_END = 60.0
_rs = np.random.default_rng(12345)
ROT_A = _rs.uniform(0.2, 0.6, (3, 3))  # (component, harmonic) amplitudes, rad
ROT_F = _rs.uniform(0.1, 0.9, (3, 3))  # Hz
ROT_C = _rs.uniform(0, 2 * np.pi, (3, 3))
POS_A = _rs.uniform(0.1, 0.3, (3, 3))  # m
POS_F = _rs.uniform(0.2, 1.0, (3, 3))
POS_C = _rs.uniform(0, 2 * np.pi, (3, 3))


def exp_so3_np(v: np.ndarray) -> np.ndarray:
    """Rodrigues' formula in plain numpy float64, kept in the tests on purpose: they build poses and
    turns with this second implementation, independent of the library's :func:`jaxcal.rotation.exp_so3`."""
    v = np.asarray(v, np.float64)
    th = np.linalg.norm(v)
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    if th < 1e-12:
        return np.eye(3) + k
    return np.eye(3) + np.sin(th) / th * k + (1 - np.cos(th)) / th**2 * (k @ k)


def fake_align(tau0: float, ppm: float, step: float = 0.0):
    """A stand-in for ``align_recording``: the window's offset at its middle from a known clock
    (``tau0 + ppm 1e-6 t``, plus ``step`` after 100 s), so the windowing is checked without a fit."""

    def align(rec, pose_sigma=None, config=None):
        mid = 0.5 * float(rec.t[0] + rec.t[-1])
        tau = tau0 + ppm * 1e-6 * mid + (step if mid > 100.0 else 0.0)
        return SimpleNamespace(align={"tau": tau, "tau_stderr": 2e-5, "clock_skew": ppm, "clock_skew_epoch_s": mid,
                                      "stderr": {"clock_skew": 1.0}, "tau_per_sensor": {}, "clock_skew_per_sensor": {}})

    return align


def _sines(t, A, F, C, d=0):
    """d-th derivative of sum_h A[c, h] sin(2 pi F[c, h] t + C[c, h]) per component c: (N, 3)."""
    w = 2 * np.pi * F
    ph = w[None] * t[:, None, None] + C[None] + d * np.pi / 2
    return np.sum(A[None] * w[None] ** d * np.sin(ph), axis=2)


def _hat(v):
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1), np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def truth_rot(t):
    return Rotation.from_rotvec(_sines(t, ROT_A, ROT_F, ROT_C))


def truth_rate(t):
    """Body rate (rad/s): w = J_r(phi) phi', J_r = I - (1 - cos th)/th^2 K + (th - sin th)/th^3 K^2."""
    phi, dphi = _sines(t, ROT_A, ROT_F, ROT_C), _sines(t, ROT_A, ROT_F, ROT_C, 1)
    th = np.linalg.norm(phi, axis=1)[:, None, None]
    K = _hat(phi)
    J = np.eye(3) - (1 - np.cos(th)) / th**2 * K + (th - np.sin(th)) / th**3 * (K @ K)
    return np.einsum("nij,nj->ni", J, dphi)


def truth_pos(t, d=0):
    return _sines(t, POS_A, POS_F, POS_C, d)


def quat_wxyz(rot):
    q = rot.as_quat()  # x, y, z, w
    return np.concatenate([q[:, 3:], q[:, :3]], 1)


def rot_of(q_wxyz):
    return Rotation.from_quat(np.concatenate([q_wxyz[:, 1:], q_wxyz[:, :1]], 1))


def make_rec(with_track: bool) -> Recording:
    """The analytic rig as a :class:`Recording` (acc in g, gyr in rad/s, pose on the IMU grid and,
    ``with_track``, a 240 Hz pose track ``gt_*`` reaching 0.5 s beyond both ends)."""
    t = np.arange(int(T_END * FS)) / FS
    rot = truth_rot(t)
    f = rot.inv().apply(truth_pos(t, 2) / G0 + np.array([0.0, 0.0, 1.0]))
    rec = {"t": t, "acc": f, "gyr": truth_rate(t), "acc_unit": "g", "gyr_unit": "rad/s",
           "pos_ref": truth_pos(t), "quat_ref": quat_wxyz(rot)}
    if with_track:
        tg = np.arange(-0.5, T_END + 0.5, 1 / 240.0)
        rec.update(gt_t=tg, gt_pos=truth_pos(tg), gt_quat=quat_wxyz(truth_rot(tg)))
    return recording_from_dict(rec, "analytic rig")


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    """``jaxcal.cli.main(argv)`` in-process: ``(exit code, stdout, stderr)``; a Python warning (which
    a user would see as another stderr line) fails the test."""
    import warnings

    from jaxcal.cli import main

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code = main([str(a) for a in argv])
    assert not [w for w in caught if not issubclass(w.category, DeprecationWarning)], [str(w.message) for w in caught]
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def linear_model_file(path):
    """A ``linear`` model file near an MPU-6050's datasheet (seeded), for the apply/export tests."""
    from jaxcal.methods import CalibrationModel
    from jaxcal.model_file import save_model

    rng = np.random.default_rng(1)
    state = {"acc": {"S": 16384.0 * (np.eye(3) + 0.01 * rng.normal(size=(3, 3))), "b": rng.normal(0, 50, 3)},
             "gyr": {"S": 7505.7 * (np.eye(3) + 0.01 * rng.normal(size=(3, 3))), "b": rng.normal(0, 20, 3)}}
    save_model(CalibrationModel("linear", ("acc", "gyr"), state, {"units": {"acc": "LSB", "gyr": "LSB"}}), path)
    return path


def labelled_poses(n: int, max_tilt_deg: float | None, seed: int, bias=(0.0, 0.0, 0.0), **extra) -> dict[str, np.ndarray]:
    """Static-like labelled accelerometer samples (counts at 16384 LSB/g plus ``bias`` and 2 LSB of
    noise): directions within ``max_tilt_deg`` of z-up (None: the whole sphere); ``extra`` fields
    added (e.g. ``temp``). Shared by test_plausibility and the issue-27 probe."""
    rng = np.random.default_rng(seed)
    f = rng.normal(size=(n, 3))
    f /= np.linalg.norm(f, axis=1, keepdims=True)
    if max_tilt_deg is not None:
        tilt = np.radians(max_tilt_deg) * np.sqrt(rng.uniform(size=n))
        az = rng.uniform(0, 2 * np.pi, n)
        f = np.stack([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)], 1)
    counts = np.round(f * 16384.0 + np.asarray(bias, float) + rng.normal(0, 2, (n, 3)))
    return dict(t=np.arange(n) / 100.0, acc=counts, acc_ref=f, fs=np.asarray(100.0), acc_lsb_per_g=np.asarray(16384.0)) | extra
