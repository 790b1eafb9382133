"""jaxcal.sweep and ``jaxcal sweep``: grouping, vmapped == one by one, sharded == unsharded,
kill-and-resume == uninterrupted, bad specs refused with one line (exit 2)."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from jaxcal import cli
from jaxcal import sweep as sw
from jaxcal.simulate.dataset2 import Dataset2Config

TINY = Dataset2Config(n_train=20, n_val=4, n_test_acc=50, n_test_gyr=50)
TINY_DICT = {"n_train": 20, "n_val": 4, "n_test_acc": 50, "n_test_gyr": 50}
ROOT = Path(__file__).resolve().parents[1]
# float32 throughout (the thesis NN path): vmapped vs one-by-one rows differ by at most 2.1e-7
# relative, sharded (4 devices) vs one device by 1.5e-7 (measured; summation order of the batched
# matmuls), about 50x below this tolerance, so float32 reduction order cannot decide the verdict.
RTOL = 1e-5


def _env(**extra):
    env = {**os.environ, **extra}
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _close_rows(a, b, rtol=RTOL):
    assert len(a) == len(b)
    worst = 0.0
    for ra, rb in zip(a, b, strict=True):
        assert ra.keys() == rb.keys()
        for k, va in ra.items():
            if isinstance(va, float) and isinstance(rb[k], float):
                worst = max(worst, abs(va - rb[k]) / max(abs(rb[k]), 1e-12))
            else:
                assert va == rb[k], k
    assert worst <= rtol, f"max relative difference {worst:.2e} > {rtol:g}"
    return worst


def test_expand_and_plan_split_static_fields_into_groups_and_batches():
    spec = sw.SweepSpec(grid={"init_every": [5, 10], "w": [0.8, 0.9, 1.0]}, random={"acc_lr": (1e-5, 1e-3, "log")},
                        n_random=2, seeds=(0, 1), dataset=TINY, batch_size=4)
    configs = sw.expand(spec)
    assert len(configs) == 2 * 3 * 2 * 2
    lrs = {c["acc_lr"] for c in configs}
    assert len(lrs) == 2 and all(1e-5 <= v <= 1e-3 for v in lrs)
    assert sw.expand(spec) == configs  # the random search is seeded
    batches = sw.plan(spec)
    # init_every is static (a shape): two groups of 12, each split into batches of 4.
    assert [b.label for b in batches] == [f"init_every={e}#{j}" for e in (5, 10) for j in range(3)]
    assert all(len(b.configs) == 4 for b in batches)
    assert [c for b in batches for c in b.configs] == configs
    # w, learning rates and seeds are traced: one group without batch_size.
    assert len(sw.plan(spec._replace(grid={"w": [0.8, 0.9]}, batch_size=0))) == 1


def test_vmapped_group_equals_each_configuration_alone():
    spec = sw.SweepSpec(grid={"w": [0.8, 1.0]}, random={"gyr_lr": (1e-5, 1e-3, "log")}, n_random=1,
                        fixed={"init_epochs": 50}, seeds=(0, 1), dataset=TINY)
    res = sw.run_sweep(spec, log=lambda _: None)
    assert len(sw.plan(spec)) == 1 and len(res.rows) == 4
    alone = [{k: r[k] for k in ("group", *res.names, "seed")} | sw.run_one(spec, c)
             for r, c in zip(res.rows, sw.expand(spec), strict=True)]
    _close_rows(res.rows, alone)
    # the swept values matter: w changes the accelerometer, seeds change everything
    assert res.rows[0]["test_acc_mg"] != res.rows[2]["test_acc_mg"]
    assert res.rows[0]["test_gyr_mrads"] != res.rows[1]["test_gyr_mrads"]


_SHARD_SNIPPET = """
import json, jax
from jaxcal import sweep as sw
from jaxcal.simulate.dataset2 import Dataset2Config
spec = sw.SweepSpec(grid={"w": [0.7, 0.8, 0.9]}, fixed={"init_epochs": 50}, seeds=(0,),
                    dataset=Dataset2Config(n_train=20, n_val=4, n_test_acc=50, n_test_gyr=50))
sharded = sw.run_sweep(spec)
single = sw.run_sweep(spec, devices=jax.devices()[:1])
print(json.dumps({"n_devices": jax.device_count(), "sharded": sharded.rows, "single": single.rows,
                  "devices_used": sharded.timing["devices"]}))
"""


def test_sharded_equals_unsharded_on_four_host_devices():
    env = _env(XLA_FLAGS="--xla_force_host_platform_device_count=4", JAX_PLATFORMS="cpu")
    out = subprocess.run([sys.executable, "-c", _SHARD_SNIPPET], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["n_devices"] == 4 and got["devices_used"] == 4
    # 3 configurations padded to 4 on 4 devices (batch 1 each) vs 3 vmapped on one device.
    _close_rows(got["sharded"], got["single"])


def _cli(*args, **kw):
    return subprocess.Popen([sys.executable, "-m", "jaxcal.cli", "sweep", *map(str, args)], env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


def test_killed_sweep_resumed_gives_the_uninterrupted_rows(tmp_path):
    cfg = tmp_path / "sweep.json"
    cfg.write_text(json.dumps({"grid": {"init_every": [5, 10], "w": [0.8, 0.9]}, "fixed": {"init_epochs": 50},
                               "seeds": [0], "dataset": TINY_DICT, "batch_size": 1}))
    full = _cli(cfg, "--out", tmp_path / "full")
    _, err = full.communicate(timeout=600)
    assert full.returncode == 0, err
    assert (tmp_path / "full" / "sweep_heatmap.png").stat().st_size > 0
    assert "Lowest gyroscope error" in (tmp_path / "full" / "sweep.md").read_text()
    rows_full = json.loads((tmp_path / "full" / "sweep.json").read_text())["rows"]
    assert len(rows_full) == 4

    killed = _cli(cfg, "--out", tmp_path / "part")
    ck = tmp_path / "part" / sw.CHECKPOINT
    t_end = time.monotonic() + 300
    while not ck.exists() and killed.poll() is None and time.monotonic() < t_end:
        time.sleep(0.01)
    killed.send_signal(signal.SIGKILL)
    killed.communicate(timeout=60)
    assert killed.returncode == -signal.SIGKILL
    n_done = len(json.loads(ck.read_text())["batches"])
    assert 1 <= n_done < 4 and not (tmp_path / "part" / "sweep.json").exists()

    again = _cli(cfg, "--out", tmp_path / "part")  # without --resume: refused, checkpoint kept
    _, err = again.communicate(timeout=120)
    assert again.returncode == 2 and "--resume" in err and len(err.strip().splitlines()) == 1

    resumed = _cli(cfg, "--out", tmp_path / "part", "--resume")
    _, err = resumed.communicate(timeout=600)
    assert resumed.returncode == 0, err
    out = json.loads((tmp_path / "part" / "sweep.json").read_text())
    assert out["timing"]["resumed"] == n_done
    assert out["rows"] == rows_full  # exactly, not within a tolerance


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("{not json", "not JSON"),
        (json.dumps({"grid": {"lr": [1e-3]}}), "unknown hyperparameter 'lr'"),
        (json.dumps({"grid": {"w": [0.9, 1.5]}}), "w = 1.5"),
        (json.dumps({"target": "torch"}), "unknown target"),
        (json.dumps({"random": {"n": 2, "params": {"acc_lr": [0, 1e-3, "log"]}}}), "acc_lr"),
        (json.dumps({"random": {"n": 2, "params": {"init_every": [5, 10, "lin"]}}}), "static"),
        (json.dumps({"seeds": [0, 0]}), "repeated seed"),
        (json.dumps({"dataset": {"n_trains": 5}}), "n_trains"),
        (json.dumps({"grid": {"w": [0.9]}, "heatmap": ["w", "acc_lr"]}), "heatmap"),
    ],
)
def test_bad_config_exits_2_with_one_line(tmp_path, capsys, text, needle):
    cfg = tmp_path / "bad.json"
    cfg.write_text(text)
    code = cli.main(["sweep", str(cfg), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and needle in err and str(cfg) in err
    assert not (tmp_path / "out").exists()


def test_example_config_parses():
    spec = sw.load_sweep_spec(ROOT / "docs" / "sweep_example.json")
    assert len(sw.expand(spec)) == 4 * 3 * 2 and len(sw.plan(spec)) == 3
    assert np.isclose(spec.fixed["init_epochs"], 5000)
