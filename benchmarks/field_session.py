"""A 10-minute 100 Hz rest-motion session (simulated, raw counts) for timing the field calibration
(issue 26: one ``jaxcal calibrate --method online`` call, its held-out folds included, in at most
60 s on 2 cores):

    python -m benchmarks.field_session /tmp/sim10min.npz
    .venv/bin/jaxcal calibrate --method online /tmp/sim10min.npz --out /tmp/m.npz -q   # timed whole, median of 3 runs

116 poses (20 s initial rest, 3 s holds, 2 s turns): 59500 samples, 595 s.
"""

from __future__ import annotations

import sys

import jax

from jaxcal.recording import Recording, save_recording
from jaxcal.simulate.multipos import simulate_poses


def main(path: str) -> None:
    t, acc, gyr = simulate_poses(jax.random.PRNGKey(7), n_poses=116, fs=100.0, rest=20.0, hold=3.0, move=2.0)
    save_recording(Recording(t=t, acc=acc, gyr=gyr, fs=100.0, acc_unit="LSB", gyr_unit="LSB"), path)
    print(f"{path}: {len(t)} samples, {t[-1]:.0f} s")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "/tmp/sim10min.npz")
