"""jaxcal.diagnose.band against closed forms: the reference gain is the errors-in-variables
attenuation S/(S+N), unbiased by sensor noise, blind to a rotation or a delay between the streams."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from jaxcal.diagnose.band import HALF_POWER, choose_sigma, coherence, reference_gain


def _streams(n=200_000, ref_noise=0.5, sens_noise=2.0, delay=0, seed=0):
    rng = np.random.default_rng(seed)
    s = rng.standard_normal((n + 50, 3))
    R = Rotation.from_rotvec([0.1, -0.05, 0.08]).as_matrix()
    y = np.roll(s, delay, axis=0)[:n] @ R.T + sens_noise * rng.standard_normal((n, 3))
    x = s[:n] + ref_noise * rng.standard_normal((n, 3))
    return y, x


def test_gain_is_the_attenuation_whatever_the_sensor_noise_rotation_and_delay():
    """White signal (var 1), reference noise var 0.25: gain 1/1.25 = 0.8 at every frequency, with
    sensor noise var 4 (coherence far lower), a 5.7 deg rotation and a 3-sample delay."""
    y, x = _streams(delay=3)
    f, g = reference_gain(y, x, np.ones(len(y), bool), 0.01)
    band = (f > 1) & (f < 45)
    # measured: mean 0.80, per-bin spread about 0.02 (100 Welch windows of 2 s)
    assert abs(np.mean(g[band]) - 0.8) < 0.01, np.mean(g[band])
    _, coh = coherence(y, x, np.ones(len(y), bool), 0.01)
    assert np.mean(coh[band]) < 0.3  # the sensor noise drags coherence down; the gain ignores it


def test_trusted_edge_matches_the_closed_form():
    """Random-walk signal (step sd q per sample) against white reference noise (sd k): the gain
    S/(S+N) falls to 0.95 where S/N = 19, i.e. 2 sin(pi f dt) = q / (k sqrt(19)). The kernel's
    half-power point sits at that edge; ten times the noise, a lower edge, a wider kernel."""
    rng = np.random.default_rng(1)
    n, dt, q = 120_000, 0.005, 0.05
    s = np.cumsum(rng.standard_normal((n, 3)), axis=0) * q
    sig = []
    for k in (0.1, 0.3):
        b = choose_sigma({"gyr": (s, s + k * rng.standard_normal((n, 3)))}, np.ones(n, bool), dt)
        f_true = np.arcsin(q / (k * np.sqrt(19.0)) / 2) / (np.pi * dt)  # 3.65 Hz, 1.22 Hz
        # measured: edges 4.0 and 1.5 Hz (Welch bins of 0.5 Hz, first bin of the 5-bin mean below 0.95)
        assert abs(b.edge_hz["gyr"] - f_true) <= 0.75, (k, b.edge_hz, f_true)
        assert abs(b.sigma_s - HALF_POWER / b.edge_hz["gyr"]) < 1e-12
        sig.append(b.sigma_s)
    assert sig[1] > 2 * sig[0]
