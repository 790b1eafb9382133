"""The contract every calibration method keeps, run over ``methods.REGISTRY`` (optax's
``_OPTIMIZERS_UNDER_TEST`` style: the parameter list is built from the registry, so a newly
registered method is run through it without touching this file).

For each method, on a small simulated recording it can fit (:mod:`jaxcal.simulate.recordings`):
fit -> save_model -> load_model -> apply gives the same calibrated arrays as the fitted model,
one ``(N, 3)`` finite array per calibrated sensor, the sensors' units recorded in the metadata,
a recording in other units refused; a recording lacking what the method needs is refused with one
line. A method without an entry in :data:`CASES` is run on a labelled recording with its default
options (what a labelled method needs; add a case for anything else).

Adding a method needs nothing but a module and one registry line:
:func:`test_a_new_method_needs_only_a_module_and_a_registry_line` registers ``tests/toy_method.py``
and runs the same contract on it, and through the CLI.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import NamedTuple

import jax
import numpy as np
import pytest
import toy_method

from jaxcal import methods
from jaxcal.cli import main
from jaxcal.methods import CubicOptions, LinearOptions, ModelError, MultiposOptions, NNOptions, OnlineOptions, OnlineThesisOptions
from jaxcal.methods.diagnosed import DiagnosedOptions
from jaxcal.model_file import load_model, save_model
from jaxcal.recording import Recording
from jaxcal.simulate import Dataset2Config
from jaxcal.simulate.recordings import dataset2_recordings, multipos_recording

SEED = 7
OTHER_UNIT = {"acc": "g", "gyr": "rad/s"}


@functools.cache
def _dataset2(labels: bool) -> Recording:
    """12 rotation sequences of Dataset 2 (1212 samples; ``seq`` ids, datasheet values)."""
    recs, _ = dataset2_recordings(SEED, Dataset2Config(n_train=12, n_val=2), labels)
    return recs["train"]


@functools.cache
def _multipos() -> Recording:
    """12 static poses joined by rotations (raw counts, no labels, no datasheet values)."""
    return multipos_recording(jax.random.PRNGKey(3), n_poses=12)


@functools.cache
def _rich() -> Recording:
    """1500 samples of rich motion with reference and a concealed gyro g-sensitivity (what
    ``diagnosed`` fits from; :mod:`jaxcal.diagnose.simulate`)."""
    from jaxcal.diagnose.simulate import RichConfig, simulate_recording

    g = np.array([[4e-3, 0, 1e-3], [0, -3e-3, 0], [2e-3, 0, 3e-3]])
    return simulate_recording(jax.random.PRNGKey(5), RichConfig(n=1500), {("gyr", "g_sensitivity"): {"G": g}})[0]


class Case(NamedTuple):
    """A method's contract inputs: a recording it fits, fast options, a recording lacking what it
    needs and a phrase its refusal says."""

    recording: Callable[[], Recording]
    options: NamedTuple | None = None
    bad: Callable[[Recording], Recording] = lambda r: r.replace(acc_ref=None, gyr_ref=None)
    needle: str = ""


CASES: dict[str, Case] = {
    "linear": Case(lambda: _dataset2(True), LinearOptions(), needle="needs reference labels"),
    "cubic": Case(lambda: _dataset2(True), CubicOptions(), needle="needs reference labels"),
    "nn": Case(lambda: _dataset2(True), NNOptions(widths=(8,), max_epochs=30, patience=10),
               needle="needs reference labels"),
    "online": Case(lambda: _dataset2(False), OnlineOptions(), lambda r: r.replace(seq=None), "needs 'seq' ids"),
    "online-thesis": Case(lambda: _dataset2(False), OnlineThesisOptions(seed=1),
                          lambda r: r.replace(acc_lsb_per_g=None), "needs the datasheet scale 'acc_lsb_per_g'"),
    "multipos": Case(_multipos, MultiposOptions(), lambda r: r.replace(gyr=None), "needs both 'acc' and 'gyr'"),
    "diagnosed": Case(_rich, DiagnosedOptions(), needle="needs reference motion"),
}
DEFAULT_CASE = Case(lambda: _dataset2(True))

_METHODS_UNDER_TEST = list(methods.REGISTRY)


def check_contract(name: str, case: Case, tmp_path) -> None:
    """fit -> save -> load -> apply, outputs, units, bad input (see the module docstring)."""
    rec = case.recording()
    model = methods.fit(name, rec, case.options)
    assert model.method == name and model.sensors and set(model.sensors) <= {"acc", "gyr"}
    assert model.meta["units"] == {s: getattr(rec, f"{s}_unit") for s in model.sensors}
    save_model(model, tmp_path / f"{name}.npz")
    loaded = load_model(tmp_path / f"{name}.npz")
    assert (loaded.method, loaded.sensors, loaded.meta["units"]) == (name, model.sensors, model.meta["units"])
    out = methods.apply(loaded, rec)
    assert set(out) == {f"{s}_cal" for s in model.sensors}
    fresh = model.apply(rec)
    for k, v in out.items():
        assert v.shape == (rec.n, 3) and v.dtype == np.float64 and np.isfinite(v).all(), k
        np.testing.assert_array_equal(v, fresh[k])  # the file keeps everything apply needs
    other = rec.replace(**{f"{s}_unit": OTHER_UNIT[s] for s in model.sensors})
    with pytest.raises(ModelError, match="the model was fitted on"):
        loaded.apply(other)
    with pytest.raises(ModelError, match=case.needle) as err:
        methods.fit(name, case.bad(rec), case.options)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("name", _METHODS_UNDER_TEST)
def test_method_contract(name, tmp_path):
    check_contract(name, CASES.get(name, DEFAULT_CASE), tmp_path)


@pytest.mark.parametrize("name", _METHODS_UNDER_TEST)
def test_options_type_holds_every_default_and_documents_every_field(name):
    m = methods.REGISTRY[name]
    assert m.name == name and m.doc and "\n" not in m.doc
    opts = m.options
    assert set(opts._field_defaults) == set(opts._fields), f"{opts.__name__}: every field needs a default"
    for f in opts._fields:
        assert f"{f}:" in (opts.__doc__ or ""), f"{opts.__name__} does not document '{f}'"
    assert isinstance(opts(), tuple)
    with pytest.raises(ModelError, match=f"takes {opts.__name__}"):
        methods.fit(name, _dataset2(True), _WrongOptions())


class _WrongOptions(NamedTuple):
    nothing: int = 0


def test_shared_option_fields_have_one_default():
    """A field several options types share (``seed``, ``sensors``) has one default, so the CLI's
    one flag for it has one default too."""
    seen: dict[str, tuple[str, object]] = {}
    for m in methods.REGISTRY.values():
        for f, d in m.options._field_defaults.items():
            if f in seen:
                assert seen[f][1] == d, (f, seen[f][0], m.name)
            seen.setdefault(f, (m.name, d))


def test_shared_option_fields_have_one_flag():
    """A field several options types declare a flag for (``FLAGS``) declares the same one, so the
    CLI's one flag for it means one thing; every declared flag names a field of its type, and no
    two fields share a flag."""
    seen: dict[str, tuple[str, object]] = {}
    for m in methods.REGISTRY.values():
        declared = getattr(m.options, "FLAGS", {})
        assert set(declared) <= set(m.options._fields), (m.name, set(declared) - set(m.options._fields))
        for f, flag in declared.items():
            if f in seen:
                assert seen[f][1] == flag, (f, seen[f][0], m.name)
            seen.setdefault(f, (m.name, flag))
    names = [flag.flag for _, flag in seen.values()]
    assert len(names) == len(set(names)), names


def test_unknown_method_is_refused():
    with pytest.raises(ModelError, match="unknown method 'voodoo' \\(known: linear, nn"):
        methods.get("voodoo")


def test_a_new_method_needs_only_a_module_and_a_registry_line(tmp_path, capsys):
    """``tests/toy_method.py`` is a method (options type, fit, apply, check); one line registers
    it; then it passes the contract and works from the command line (``--method toy-diag``)."""
    methods.register(toy_method.METHOD)  # the one registry line
    try:
        assert "toy-diag" in methods.names()
        check_contract("toy-diag", Case(lambda: _dataset2(True), needle="needs reference labels"), tmp_path)
        rec_path = tmp_path / "rec.npz"
        from jaxcal.recording import save_recording

        save_recording(_dataset2(True), rec_path)
        assert main(["calibrate", "--method", "toy-diag", str(rec_path), "--out", str(tmp_path / "m.npz"), "-q"]) == 0
        assert main(["apply", str(tmp_path / "m.npz"), str(rec_path), "--out", str(tmp_path / "c.npz"), "-q"]) == 0
        assert main(["methods"]) == 0 and "toy-diag" in capsys.readouterr().out
        # the true model is diagonal (Dataset 2, eq. 4.6): the toy recovers the labels to quantisation noise
        with np.load(tmp_path / "c.npz") as z:
            np.testing.assert_allclose(z["acc_cal"], _dataset2(True).acc_ref, atol=2e-4)
        # its own option's flag, declared on its options type only (no edit in jaxcal/cli)
        assert main(["calibrate", "--method", "toy-diag", str(rec_path), "--out", str(tmp_path / "o.npz"), "-q",
                     "--through-origin"]) == 0
        st, rec = load_model(tmp_path / "o.npz").state["acc"], _dataset2(True)
        x, y = rec.acc_ref, np.asarray(rec.acc, np.float64)
        np.testing.assert_array_equal(st["b"], 0.0)
        np.testing.assert_allclose(np.diag(st["S"]), (x * y).sum(0) / (x * x).sum(0), rtol=1e-12)
    finally:
        methods.REGISTRY.pop("toy-diag")
    assert "toy-diag" not in methods.names()
