"""The vocabulary as one record per effect (issue 26 part 1): every table comes from the records,
each record's inverse undoes its forward step, and a new effect needs one record and one
registry line (``tests/toy_effect.py``), found by ``diagnose`` and inverted by ``diagnosed``.

Truth: closed forms (a forward step followed by its inverse is the identity), and a toy effect
concealed in a simulated recording with known parameters (its rates ``gyr_ref`` are the truth the
``diagnosed`` model's output is scored against).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcal.diagnose import effects as E
from jaxcal.diagnose import vocabulary as V
from tests import toy_effect


def test_every_table_comes_from_the_records():
    for e in V.REGISTRY.values():
        for s in e.sensors:
            assert E.UNITS[(e.name, s)] == e.units[s]
            assert E.PLAUSIBLE_RANGE.get((e.name, s)) == e.plausible_range.get(s)
        if e.stage is not None:
            assert E.EXCITE[e.name] == e.excites
    assert E.EFFECT_NAMES == tuple(V.REGISTRY)
    for s in ("acc", "gyr"):
        starts = [sl.start for sl in E.LAYOUT[s]]
        sizes = [sl.size for sl in E.LAYOUT[s]]
        assert starts == list(np.cumsum([0] + sizes[:-1])) and E.N_THETA[s] == sum(sizes)


def _inputs(n=400, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 0.01
    w = np.stack([np.sin(2 * np.pi * 0.5 * t + k) * (1 + k) for k in range(3)], 1)
    f = np.stack([np.cos(2 * np.pi * 0.3 * t + k) for k in range(3)], 1) * 0.5 + np.array([0, 0, 1.0])
    return E.Inputs(jnp.asarray(f), jnp.asarray(w), jnp.asarray(np.gradient(w, 0.01, axis=0)), jnp.asarray(t - t.mean()),
                    jnp.asarray(2.0 * np.sin(t) + rng.standard_normal(n) * 0.0), jnp.asarray(0.01))


@pytest.mark.parametrize("name", [e.name for e in V.REGISTRY.values() if e.inverse is not None])
def test_inverse_undoes_forward(x64, name):
    """``inverse(forward(x)) = x`` at a size well inside the plausible range, exactly (to rounding)
    where the inverse is a closed form; a time shift (Fourier forward, spline inverse) to 2e-5 on
    the interior of a 4-s signal whose even extension has a kink at the ends (measured 4e-6), a
    shift that moved the signal by more than 1e-3."""
    e = V.get(name)
    s = e.sensors[-1]
    inp = _inputs()
    rng = np.random.default_rng(3)
    flat = rng.uniform(-0.2, 0.2, e.size) * e.plausible_range[s] / (100.0 if name == "time_offset" else 1.0)
    x = np.asarray(inp.w)
    y = np.asarray(e.forward(jnp.asarray(flat), jnp.asarray(x), inp))
    t = np.asarray(inp.tc)
    back = e.inverse(np.asarray(e.public(flat), np.float64), y, V.InverseContext(t, [slice(0, len(t))], np.asarray(inp.dT)[:, None]))
    inner = slice(20, -20) if name == "time_offset" else slice(None)
    tol = 2e-5 if name == "time_offset" else 1e-12
    assert np.max(np.abs(y - x)) > 1e-3
    assert np.max(np.abs(back[inner] - x[inner])) < tol


@pytest.fixture
def toy_registered():
    V.register(toy_effect.EFFECT)
    try:
        yield toy_effect.EFFECT
    finally:
        V.unregister(toy_effect.EFFECT.name)


K3 = np.array([2e-3, -1e-3, 1.5e-3])


def test_a_new_effect_needs_only_a_record_and_a_registry_line(toy_registered):
    from jaxcal.diagnose import diagnose_recording
    from jaxcal.diagnose.simulate import RichConfig, simulate_recording
    from jaxcal.methods import diagnosed as D

    assert "toy_cubic" in E.EFFECT_NAMES and ("toy_cubic", "gyr") in E.PLAUSIBLE_RANGE and "toy_cubic" in D.CARRIED
    rec, truth = simulate_recording(jax.random.PRNGKey(7), RichConfig(n=4000), {("gyr", "toy_cubic"): {"k3": K3}})
    rep = diagnose_recording(rec, keep_fit=True)
    hit = [e for e in rep["effects"] if (e["sensor"], e["name"]) == ("gyr", "toy_cubic")]
    assert hit, f"toy effect not named; effects {[(e['sensor'], e['name']) for e in rep['effects']]}"
    est, se = np.asarray(hit[0]["params"]["k3"]), np.asarray(hit[0]["stderr"]["k3"])
    assert np.all(np.abs(est - K3) < 4.5 * se), (est, K3, se)
    assert hit[0]["heldout_rms_after"] < hit[0]["heldout_rms_before"]
    assert rep["plausible_range"]["gyr toy_cubic"]["unit"] == "1/(rad/s)^2"
    # the diagnosed model carries it, and its inverse brings the output closer to the true rates
    fitted = D.diagnosed_model_state(*rep["_fit"], "diag", rec)
    assert "toy_cubic" in fitted.state["gyr"] and "toy_cubic" in fitted.meta["effects"]["gyr"]
    D.check(fitted.state, fitted.meta, fitted.sensors)
    without = {s: {k: v for k, v in p.items() if k != "toy_cubic"} for s, p in fitted.state.items()}
    ref = np.asarray(rec.gyr_ref)

    def rms(state):
        return float(np.sqrt(np.mean((D.apply(state, fitted.meta, rec)["gyr_cal"] - ref)[100:-100] ** 2)))

    assert rms(fitted.state) < 0.5 * rms(without)
