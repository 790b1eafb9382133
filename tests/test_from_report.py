"""``jaxcal calibrate --from-diagnose``: what a ``jaxcal diagnose`` report names switches on the options
that model it (issue 26, "use what diagnose finds"); :mod:`jaxcal.methods.from_report`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import run_cli

from jaxcal import methods
from jaxcal.diagnose import vocabulary as V
from jaxcal.methods.base import GSENS_KEY
from jaxcal.methods.from_report import named_in_report, options_from_report
from jaxcal.methods.linear import LinearOptions
from jaxcal.methods.online import OnlineOptions
from jaxcal.model_file import load_model

MPU = Path(__file__).resolve().parent.parent / "data" / "tomisuarez_mpu6050" / "calibration.npz"

REPORT = {"effects": [
    {"name": "g_sensitivity", "sensor": "gyr", "params": {}},
    {"name": "lever_arm", "sensor": "acc", "params": {}},
    {"name": "time_offset", "sensor": "acc", "params": {}, "forced": True},  # estimated on request: not a finding
]}


def test_a_named_effect_switches_on_its_option_and_the_rest_is_listed():
    out = options_from_report(OnlineOptions(), REPORT)
    assert out.options == OnlineOptions(g_sensitivity=True)
    assert out.modelled == ("gyr g_sensitivity",)
    assert out.not_modelled == ("acc lever_arm",)
    assert options_from_report(OnlineOptions(), {"effects": []}).options == OnlineOptions()


def test_a_method_without_effects_models_none_of_them():
    out = options_from_report(LinearOptions(), REPORT)
    assert out.options == LinearOptions()
    assert out.modelled == () and out.not_modelled == ("gyr g_sensitivity", "acc lever_arm")


@pytest.mark.parametrize("bad", [[], {"effects": {}}, {"effects": [{"name": "g_sensitivity"}]}, {"effects": [3]}])
def test_what_is_not_a_report_is_refused(bad):
    with pytest.raises(ValueError, match="not a `jaxcal diagnose` report"):
        named_in_report(bad)


@pytest.mark.parametrize("name", list(methods.REGISTRY))
def test_every_declared_effect_is_a_vocabulary_effect_and_a_boolean_option_off_by_default(name):
    kind = methods.REGISTRY[name].options
    for (sensor, effect), field in getattr(kind, "EFFECTS", {}).items():
        assert effect in V.REGISTRY and sensor in ("acc", "gyr"), (sensor, effect)
        assert kind._field_defaults[field] is False, field


def test_calibrate_from_a_report_fits_what_it_names(tmp_path, capsys):
    """On the real MPU-6050 session, a report naming the gyroscope's g-sensitivity gives a
    ``multipos`` model with ``G``; the same call without the report has none."""
    if not MPU.exists():
        pytest.skip("data/tomisuarez_mpu6050 not present")
    diag = tmp_path / "diag"
    diag.mkdir()
    (diag / "report.json").write_text(json.dumps(REPORT))
    code, _, err = run_cli(capsys, "calibrate", MPU, "--method", "multipos", "--no-held-out", "-q",
                           "--out", tmp_path / "g.npz", "--from-diagnose", diag)
    assert code == 0, err
    assert "multipos models gyr g_sensitivity; not in multipos's model: acc lever_arm" in err
    m = load_model(tmp_path / "g.npz")
    assert np.asarray(m.state["gyr"][GSENS_KEY]).shape == (3, 3)
    assert m.meta["from_diagnose"] == {"report": str(diag), "modelled": ["gyr g_sensitivity"],
                                       "not_modelled": ["acc lever_arm"]}
    code, _, err = run_cli(capsys, "calibrate", MPU, "--method", "multipos", "--no-held-out", "-q",
                           "--out", tmp_path / "plain.npz")
    assert code == 0, err
    assert GSENS_KEY not in load_model(tmp_path / "plain.npz").state["gyr"]


@pytest.mark.parametrize("text, needle", [(None, "cannot read"), ("{", "Expecting"), ('{"effects": 1}', "no `effects` list")])
def test_a_missing_or_malformed_report_is_a_usage_error(tmp_path, capsys, text, needle):
    f = tmp_path / "report.json"
    if text is not None:
        f.write_text(text)
    code, _, err = run_cli(capsys, "calibrate", tmp_path / "never_read.npz", "--method", "multipos",
                           "--out", tmp_path / "m.npz", "--from-diagnose", f)
    assert code == 2 and "--from-diagnose" in err and needle in err, err
    assert not (tmp_path / "m.npz").exists()
