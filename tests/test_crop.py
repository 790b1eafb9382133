"""`jaxcal crop` and `jaxcal.recording.crop`: a stretch of a recording that every command reads."""

from __future__ import annotations

import numpy as np
import pytest

from jaxcal.recording import Recording, crop, load_recording, save_recording
from tests.helpers import run_cli


def _rec(n: int = 1000, fs: float = 100.0) -> Recording:
    t = 5.0 + np.arange(n) / fs
    rng = np.random.default_rng(0)
    gt_t = 5.0 + np.arange(n // 2) / (fs / 2)
    return Recording(t=t, acc=rng.normal(size=(n, 3)), gyr=rng.normal(size=(n, 3)), acc_unit="g", gyr_unit="rad/s",
                     gt_t=gt_t, gt_pos=rng.normal(size=(n // 2, 3)), gt_quat=np.tile([1.0, 0, 0, 0], (n // 2, 1)))


def test_crop_keeps_the_stretch_and_its_reference_track():
    rec = _rec()
    out = crop(rec, 2.0, 4.5)
    rel = rec.t - rec.t[0]
    keep = (rel >= 2.0) & (rel < 4.5)
    np.testing.assert_array_equal(out.t, rec.t[keep])
    np.testing.assert_array_equal(out.acc, rec.acc[keep])
    assert out.n == 250
    g = (rec.gt_t >= rec.t[0] + 2.0) & (rec.gt_t < rec.t[0] + 4.5)
    np.testing.assert_array_equal(out.gt_t, rec.gt_t[g])
    np.testing.assert_array_equal(out.gt_pos, rec.gt_pos[g])
    np.testing.assert_array_equal(crop(rec, 0.0).acc, rec.acc)  # no end: to the end


@pytest.mark.parametrize("start,end", [(-1.0, 2.0), (3.0, 3.0), (20.0, None)])
def test_crop_refuses_an_empty_or_backwards_stretch(start, end):
    with pytest.raises(ValueError):
        crop(_rec(), start, end)


def test_cli_crop_writes_a_recording_the_commands_read(tmp_path, capsys):
    src = tmp_path / "rec.npz"
    save_recording(_rec(), src)
    code, _, err = run_cli(capsys, "crop", src, "--start", "1", "--end", "3", "--out", tmp_path / "c.npz")
    assert code == 0, err
    out = load_recording(tmp_path / "c.npz")
    assert out.n == 200 and "200 of 1000 samples" in err
    code, _, err = run_cli(capsys, "crop", src, "--start", "3", "--end", "1", "--out", tmp_path / "d.npz")
    assert code == 2 and "--end" in err and not (tmp_path / "d.npz").exists()
