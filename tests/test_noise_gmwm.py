"""jaxcal.gmwm: the composite-model AVAR and its covariance against closed forms and a brute-force second
implementation, and known simulated parameters recovered with the right model and covering intervals."""

import numpy as np
import pytest

from jaxcal import gmwm
from jaxcal.allan import fit_noise, overlapping_adev, simulate_imu_noise
from jaxcal.noise import gauss_markov_adev

FS = 100.0
P = {"N": 2e-4, "Q": 1e-5, "B": 1e-5, "K": 2e-6, "R": 1e-8, "sigma_gm": 3e-5, "tau_gm": 0.5}


def test_model_avar_matches_the_ieee_closed_forms():
    m = np.array([1, 4, 64, 1024, 16384])
    tau = m / FS
    for proc, want in [("WN", P["N"] ** 2 / tau), ("QN", 3 * P["Q"] ** 2 / tau**2), ("DR", P["R"] ** 2 * tau**2 / 2),
                       ("BI", np.full(m.size, 2 * np.log(2) / np.pi * P["B"] ** 2)),
                       ("RW", P["K"] ** 2 * tau / 3 * (1 + 1 / (2 * m**2)))]:  # discrete RW: K^2 tau/3 + K^2/(6 fs^2 tau)
        np.testing.assert_allclose(gmwm.model_avar((proc,), P, m, FS), want, rtol=1e-12, err_msg=proc)
    # a Gauss-Markov term tends to the continuous closed form once m >> 1 (measured: 1.2e-4 at m = 64)
    p = dict(P, tau_gm=50.0)
    got = gmwm.model_avar(("GM",), p, m[2:], FS)
    np.testing.assert_allclose(got, gauss_markov_adev(tau[2:], p["sigma_gm"], 50.0) ** 2, rtol=1e-3)


def _brute_covariance(model, p, m, n):
    """Cov of the overlapping AVAR estimates from the explicit covariance of n samples (second implementation)."""
    eye = np.eye(n)
    parts = []
    if "WN" in model:
        parts.append(p["N"] * np.sqrt(FS) * eye)
    if "RW" in model:
        parts.append(p["K"] / np.sqrt(FS) * np.tril(np.ones((n, n))))
    if "GM" in model:
        phi = np.exp(-1 / (FS * p["tau_gm"]))
        i, j = np.indices((n, n))
        gm = np.where(j <= i, p["sigma_gm"] * np.sqrt(1 - phi**2) * phi ** np.abs(i - j), 0.0)
        gm[:, 0] = p["sigma_gm"] * phi ** np.arange(n)
        parts.append(gm)
    if "QN" in model:
        d = np.zeros((n, n + 1))
        d[np.arange(n), np.arange(n)], d[np.arange(n), np.arange(n) + 1] = -1.0, 1.0
        parts.append(p["Q"] * FS * d)
    sigma = sum(a @ a.T for a in parts)
    ops = []
    for mm in m:
        k = n + 1 - 2 * mm
        a = np.zeros((k, n))
        for r in range(k):
            a[r, r:r + mm], a[r, r + mm:r + 2 * mm] = -1.0 / mm, 1.0 / mm
        ops.append(a)
    left = [a @ sigma for a in ops]
    mean = np.array([np.sum(s * a) / (2 * a.shape[0]) for s, a in zip(left, ops)])
    cov = np.array([[2 * np.sum((s @ b.T) ** 2) / (4 * a.shape[0] * b.shape[0]) for b in ops] for s, a in zip(left, ops)])
    return mean, cov


@pytest.mark.parametrize("model", [("WN",), ("RW",), ("QN",), ("GM",), ("WN", "QN", "RW", "GM")])
def test_covariance_matches_brute_force(model):
    m, n = np.array([1, 2, 4, 8, 16, 32, 64, 128]), 400  # pieces over 64 lags are integrated, not enumerated
    mean, cov = _brute_covariance(model, P, m, n)
    np.testing.assert_allclose(gmwm.model_avar(model, P, m, FS), mean, rtol=1e-10)
    # measured: at most 9.9e-5 relative (the Euler-Maclaurin term left out of the integrated pieces)
    np.testing.assert_allclose(gmwm.avar_covariance(model, P, m, n, FS), cov, rtol=1e-3)


def _fit_one(seed, n, N, K, **kw):
    x = simulate_imu_noise(np.random.default_rng(seed), n, 200.0, N, K=K, **kw)
    return x, gmwm.gmwm_axes(x, 200.0)[0]


def test_euroc_accelerometer_values_recovered_where_the_slope_line_is_not():
    """Issue 29's case: 1 h at 200 Hz with EuRoC's accelerometer values; random walk meets white noise at 1.2 s."""
    N, K = 2.0e-3, 3.0e-3
    x, f = _fit_one(3, 720_000, N, K)
    assert f.model == ("WN", "RW")
    (n_, n_lo, n_hi), (k_, k_lo, k_hi) = f.get("N"), f.get("K")
    assert n_lo <= N <= n_hi and k_lo <= K <= k_hi
    # measured on seed 3: N +0.06 %, K +0.05 %; over 16 seeds, median N error -0.0 %, K +0.5 %
    assert n_ == pytest.approx(N, rel=0.02) and k_ == pytest.approx(K, rel=0.2)
    slope = fit_noise(overlapping_adev(x, 200.0)).N[0]
    assert slope > 1.2 * N  # the reading at tau = 1 s holds the random walk too (measured +35 %; issue 29: 37 % high)


def test_gauss_markov_bias_selected_and_recovered():
    N, K, tau = 2e-4, 2e-4 * np.sqrt(3) / 10.0, 5.0
    sigma = 1.5 * N / np.sqrt(1.89 * tau) / gauss_markov_adev(np.array([1.89 * tau]), 1.0, tau)[0]
    _, f = _fit_one(1, 720_000, N, K, B=sigma, tau_b=tau)
    assert f.model == ("WN", "RW", "GM")
    for name, truth in (("N", N), ("K", K), ("sigma_gm", sigma), ("tau_gm", tau)):
        v, lo, hi = f.get(name)
        assert lo <= truth <= hi, (name, v / truth)


def test_record_length_prediction_is_consistent():
    _, f = _fit_one(2, 200_000, 2e-4, 2e-4 * np.sqrt(3) / 10.0)
    i = f.names.index("K")
    assert gmwm.predicted_halfwidth(f, "K", f.n) == pytest.approx(f.hi[i] / f.value[i] - 1.0, rel=1e-9)
    now = f.hi[i] / f.value[i] - 1.0
    sec = gmwm.record_length(f, "K", now / 2.0)
    # half the width needs about four times the log (measured 3.5x): the width falls about like 1/sqrt(length)
    assert 3.0 < sec * f.fs / f.n < 6.0
    assert gmwm.predicted_halfwidth(f, "K", int(sec * f.fs)) == pytest.approx(now / 2.0, rel=0.02)


def test_quantised_rate_adds_ieee_quantisation_noise():
    q = 1e-3
    step = np.sqrt(12) * q
    rng = np.random.default_rng(0)
    x = 3.0 * step * FS * rng.standard_normal((200_000, 1))  # the angle moves by about 3 quanta a sample
    y = gmwm.quantised_rate(rng, x, FS, q)
    steps = np.cumsum(y) / FS / step
    assert np.allclose(steps - steps[0], np.round(steps - steps[0]), atol=1e-6)  # the angle moves by whole quanta
    taus = np.array([1, 2, 4, 8]) / FS
    added = overlapping_adev(y - x, FS, taus=taus).adev[:, 0] ** 2  # what the quantisation added
    # measured: within 0.6 % of 3 Q^2 / tau^2 at these four cluster times
    np.testing.assert_allclose(added, 3 * q**2 / taus**2, rtol=0.03)
