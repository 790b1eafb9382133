"""`jaxcal calibrate --method nn` with its defaults on a nonlinear accelerometer (issue 16).

The Dataset 1 surrogate's sensor has few-mg quadratic, cubic and cross-axis terms that no linear
model can follow; its oracle floor (noise + label error) is ~0.94 mg and the linear model reaches
~2.3 mg. The NN the command line gives a user must get well under the linear model with 1000
labelled orientations (the thesis's halving at l = 1000), in seconds to minutes on a CPU.
"""

from __future__ import annotations

import numpy as np
import pytest

from jaxcal import load_model, save_recording
from jaxcal.cli import main
from jaxcal.methods import apply
from jaxcal.simulate.recordings import dataset1_recordings


@pytest.fixture(scope="module")
def recs():
    return dataset1_recordings(0)[0]


def _test_error_mg(tmp_path, recs, method: str) -> float:
    train = tmp_path / "train.npz"
    if not train.exists():
        save_recording(recs["train"], train)
    out = tmp_path / f"{method}.npz"
    assert main(["calibrate", str(train), "--method", method, "--out", str(out), "-q"]) == 0
    cal = apply(load_model(out), recs["test"])["acc_cal"]
    return 1e3 * float(np.linalg.norm(cal - recs["test"].acc_ref, axis=1).mean())


def test_nn_defaults_reach_under_0_6_of_linear(tmp_path, recs):
    """Defaults only (warm start + Adam, early stopping): measured 1.03 mg vs linear 2.27 mg (0.45x,
    2401 epochs, 27 s on 2 cores); the thesis's NN/linear ratio at l = 1000 is 0.54. The bound 0.6 is
    issue 16's acceptance point."""
    lin = _test_error_mg(tmp_path, recs, "linear")
    nn = _test_error_mg(tmp_path, recs, "nn")
    assert 1.5 < lin < 3.0  # the linear model is limited by the nonlinearity (measured 2.27 mg)
    assert nn <= 0.6 * lin, (nn, lin)
    meta = load_model(tmp_path / "nn.npz").meta
    assert meta["epochs"]["acc"] < meta["max_epochs"]  # stopped early, not at the cap
