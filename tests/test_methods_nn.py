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


def _test_error_mg(tmp_path, recs, method: str, *flags: str) -> float:
    train = tmp_path / "train.npz"
    if not train.exists():
        save_recording(recs["train"], train)
    out = tmp_path / f"{method}.npz"
    assert main(["calibrate", str(train), "--method", method, *flags, "--out", str(out), "-q"]) == 0
    cal = apply(load_model(out), recs["test"])["acc_cal"]
    return 1e3 * float(np.linalg.norm(cal - recs["test"].acc_ref, axis=1).mean())


@pytest.mark.slow
def test_nn_defaults_reach_under_0_6_of_linear(tmp_path, recs):
    """Defaults only (warm start + Adam, early stopping): measured 1.03 mg vs linear 2.27 mg (0.45x,
    2401 epochs, 27 s on 2 cores); the thesis's NN/linear ratio at l = 1000 is 0.54. The bound 0.6 is
    issue 16's acceptance point.

    Fast cover: tests/test_methods_nn.py::test_nn_default_recipe_at_1024_units_reaches_under_0_6_of_linear
    (the same command, recipe and bound with every default but the hidden width)
    """
    lin = _test_error_mg(tmp_path, recs, "linear")
    nn = _test_error_mg(tmp_path, recs, "nn")
    assert 1.5 < lin < 3.0  # the linear model is limited by the nonlinearity (measured 2.27 mg)
    assert nn <= 0.6 * lin, (nn, lin)
    meta = load_model(tmp_path / "nn.npz").meta
    assert meta["epochs"]["acc"] < meta["max_epochs"]  # stopped early, not at the cap


def test_nn_default_recipe_at_1024_units_reaches_under_0_6_of_linear(tmp_path, recs):
    """The command line's NN recipe (every default: ridge warm start, Adam 3e-5, relative early
    stopping, 15 % held out) with 1024 hidden units instead of 7500 still gets under issue 16's bound
    0.6 x linear on the nonlinear surrogate: measured 1.17 mg vs 2.27 mg (0.51x, 2164 epochs of 5000,
    7-13 s on 2 loaded cores); seeds 1 and 2 gave 0.50x and 0.49x, 512 units 0.53-0.58x (too close)."""
    lin = _test_error_mg(tmp_path, recs, "linear")
    nn = _test_error_mg(tmp_path, recs, "nn", "--widths", "1024")
    assert 1.5 < lin < 3.0  # the linear model is limited by the nonlinearity (measured 2.27 mg)
    assert nn <= 0.6 * lin, (nn, lin)
    meta = load_model(tmp_path / "nn.npz").meta
    assert meta["widths"] == [1024] and meta["epochs"]["acc"] < meta["max_epochs"]  # stopped early, not at the cap
