"""jaxcal.sweep and ``jaxcal sweep``: grouping, vmapped == one by one, sharded == unsharded,
kill-and-resume == uninterrupted, bad specs refused with one line (exit 2), and a new target
(``tests/toy_sweep_target.py``) that needs only its module and one registry line."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import toy_sweep_target

from jaxcal import cli
from jaxcal import sweep as sw
from jaxcal.simulate.dataset2 import Dataset2Config
from jaxcal.sweep import plan as sw_plan
from jaxcal.sweep import run as sw_run
from jaxcal.sweep import spec as sw_spec
from jaxcal.sweep import targets
from jaxcal.sweep.targets import offline_nn

TINY = Dataset2Config(n_train=20, n_val=4, n_test_acc=50, n_test_gyr=50)
TINY_DICT = {"n_train": 20, "n_val": 4, "n_test_acc": 50, "n_test_gyr": 50}
ROOT = Path(__file__).resolve().parents[1]
# float32 throughout (the thesis NN path): vmapped vs one-by-one rows differ by at most 2.1e-7
# relative, sharded (4 devices) vs one device by 1.5e-7 (measured; summation order of the batched
# matmuls), about 50x below this tolerance, so float32 reduction order cannot decide the verdict.
RTOL = 1e-5
# offline-nn: the tiny chapter-3 network (3-16-3 on l = 50 rows, at most 50 epochs), a few seconds.
OFFLINE_TINY = {"width": 16, "l": 50, "max_epochs": 50, "patience": 5, "row_chunk": 20}


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


# One batch of 2 seeds, 2 initial trainings and 4 configurations: the vmapped test, the sharded test's
# unsharded side and test_a_row_does_not_depend_on_the_batch_it_ran_in's batches of 4 share its compiled
# call (most of these tests' time is compiling; the module keeps jax's in-memory cache until its end).
VMAPPED = sw.SweepSpec(grid={"w": [0.8, 1.0]}, random={"gyr_lr": (1e-5, 1e-3, "log")}, n_random=1,
                       fixed={"init_epochs": 50}, seeds=(0, 1), dataset=TINY)


def test_vmapped_group_equals_each_configuration_alone():
    spec = VMAPPED
    res = sw.run_sweep(spec, log=lambda _: None)
    assert len(sw.plan(spec)) == 1 and len(res.rows) == 4
    alone = [{k: r[k] for k in ("group", *res.names, "seed")} | sw.run_one(spec, c)
             for r, c in zip(res.rows, sw.expand(spec), strict=True)]
    _close_rows(res.rows, alone)
    # the swept values matter: w changes the accelerometer, seeds change everything
    assert res.rows[0]["test_acc_mg"] != res.rows[2]["test_acc_mg"]
    assert res.rows[0]["test_gyr_mrads"] != res.rows[1]["test_gyr_mrads"]


def test_a_row_does_not_depend_on_the_batch_it_ran_in():
    """Issue 30: each distinct initial training (seed, init_lr, ...) runs once, unbatched, so its
    numbers are the same in every batch; the rows at batch sizes 2, 4 and 8 stay far closer to
    run_one than seeds are to each other. (init_lr first: a batch of 4 then holds 2 initial trainings
    shared by 4 configurations, the shape of VMAPPED's batch, and reuses its compiled call.)"""
    spec = sw.SweepSpec(grid={"init_lr": [3e-3, 1e-2], "w": [0.8, 1.0]}, fixed={"init_epochs": 50}, seeds=(0, 1),
                        dataset=TINY)
    configs = sw.expand(spec)
    alone = [sw.run_one(spec, c) for c in configs]
    runs = {b: sw.run_sweep(spec._replace(batch_size=b)).rows for b in (2, 4, 8)}
    init = ("init_loss_acc", "init_loss_gyr", "init_test_acc_mg", "init_test_gyr_mrads")
    for rows in runs.values():
        assert [{k: r[k] for k in init} for r in rows] == [{k: r[k] for k in init} for r in runs[8]]  # exactly
    acc = np.asarray([a["test_acc_mg"] for a in alone]).reshape(-1, 2)  # configurations x seeds 0, 1
    seed_spread = float((np.abs(acc[:, 0] - acc[:, 1]) / acc.mean(1)).min())
    worst = max(_close_rows(rows, [{k: r[k] for k in ("group", *spec.grid, "seed")} | a for r, a in zip(rows, alone, strict=True)])
                for rows in runs.values())
    assert 10 * worst < seed_spread  # measured: 1.1e-7 against 7e-2


def test_offline_nn_vmapped_groups_equal_each_configuration_alone():
    # warm_start is static: two groups; seed 5 takes the fold_in key rule, seed 0 the split one.
    spec = sw.SweepSpec(target="offline-nn", grid={"lr": [3e-3, 3e-2], "warm_start": [True, False]},
                        fixed=OFFLINE_TINY, seeds=(0, 5))
    assert [b.key[2] for b in sw.plan(spec)] == [("warm_start", True), ("warm_start", False)]
    res = sw.run_sweep(spec)
    configs = sw.expand(spec)
    assert [{k: r[k] for k in (*res.names, "seed")} for r in res.rows] == configs  # expand's order across groups
    # The reference is experiments/offline.py's own path (jaxcal.offline.nn_calibrate_rows, a static
    # NNTrainSpec and an optax schedule), one configuration at a time: worst 3.5e-7 relative (measured),
    # and the same epochs, best epochs and cap flags exactly.
    alone = [{k: r[k] for k in ("group", *res.names, "seed")} | sw.run_one(spec, c) for r, c in zip(res.rows, configs, strict=True)]
    _close_rows(res.rows, alone)
    # the comparison covers early stopping (patience 5) as well as the cap, and the values differ by setting
    assert {r["hit_cap"] for r in res.rows} == {True, False}
    assert any(r["epochs"] < 50 and r["best_epoch"] >= 0 for r in res.rows)
    assert len({round(r["test_mg"], 3) for r in res.rows}) == len(res.rows)
    # the linear model depends on the seed's rows only, not on the NN settings
    assert {r["seed"]: r["linear_mg"] for r in res.rows[:2]} == {r["seed"]: r["linear_mg"] for r in res.rows[-2:]}
    assert all(2.0 < r["linear_mg"] < 3.0 for r in res.rows)  # thesis Table 3.1 linear at l = 50: 2.16 mg


def test_offline_nn_groups_by_static_fields():
    spec = sw.SweepSpec(target="offline-nn", grid={"width": [16, 32], "lr": [1e-3, 3e-3]},
                        random={"patience": (5, 50, "lin"), "min_rel_delta": (1e-4, 1e-2, "log")}, n_random=2,
                        fixed={"l": 50, "max_epochs": 50}, seeds=(0, 1))
    configs = sw.expand(spec)
    assert len(configs) == 2 * 2 * 2 * 2 and all(isinstance(c["patience"], int) for c in configs)
    batches = sw.plan(spec)
    # width sets shapes: two groups of 8; lr, patience, min_rel_delta and seeds are traced
    assert [len(b.configs) for b in batches] == [8, 8]
    assert [dict(b.key)["width"] for b in batches] == [16, 32]
    assert all(dict(b.key)["l"] == 50 and dict(b.key)["warm_start"] is True for b in batches)
    assert len(sw.plan(spec._replace(grid={"lr": [1e-3, 3e-3]}))) == 1
    assert len(sw.plan(spec._replace(grid={"l": [50, 100], "row_chunk": [0, 20]}, fixed={"max_epochs": 50}))) == 4


def test_offline_nn_seeds_are_the_chapter_3_experiments_keys_and_rows():
    import jax

    from jaxcal.offline import THESIS_SIZES
    from jaxcal.simulate.dataset1 import nested_subset_weights

    # experiments/offline.py: seed_keys = split(PRNGKey(1), n_seeds); init, perm = split(seed_key)
    seed_keys = jax.random.split(jax.random.PRNGKey(1), 5)
    data, _ = offline_nn.offline_data()
    for s in (0, 4):
        init_key, perm_key = sw.offline_seed_keys(s)
        want_init, want_perm = jax.random.split(seed_keys[s])
        assert np.array_equal(init_key, want_init) and np.array_equal(perm_key, want_perm)
        sel = np.asarray(nested_subset_weights(want_perm, 1000, THESIS_SIZES))[THESIS_SIZES.index(50)] > 0
        _, y, x = offline_nn.offline_rows(data, s, 50)
        assert np.array_equal(y, np.asarray(data.train.acc)[sel]) and np.array_equal(x, np.asarray(data.train.acc_ref)[sel])
    base = jax.random.fold_in(jax.random.PRNGKey(1), 7)
    assert np.array_equal(sw.offline_seed_keys(7)[0], jax.random.split(base)[0])


_SHARD_SNIPPET = """
import json, sys, jax
from jaxcal import sweep as sw
spec = sw.spec_from_dict(json.loads(sys.argv[1]))
res = sw.run_sweep(spec)
print(json.dumps({"n_devices": jax.device_count(), "devices_used": res.timing["devices"], "rows": res.rows}))
"""


def _sharded_rows(spec: sw.SweepSpec, n_devices: int) -> list[dict]:
    """``spec``'s rows from a fresh process with ``n_devices`` host CPU devices (the flag must be set
    before jax starts), every batch sharded over all of them."""
    env = _env(XLA_FLAGS=f"--xla_force_host_platform_device_count={n_devices}", JAX_PLATFORMS="cpu")
    out = subprocess.run([sys.executable, "-c", _SHARD_SNIPPET, json.dumps(sw.spec_to_dict(spec))], env=env,
                         capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["n_devices"] == got["devices_used"] == n_devices
    return got["rows"]


def test_sharded_equals_unsharded_on_three_host_devices():
    """4 configurations padded to 6 on 3 devices (2 each) vs the 4 vmapped on this process's one
    device (VMAPPED's batch, compiled here already): float32 summation order of the batched matmuls
    only, measured 1.1e-7 relative (before, 4 devices with 3 configurations padded to 4: 1.5e-7)."""
    sharded = _sharded_rows(VMAPPED, 3)
    _close_rows(sharded, sw.run_sweep(VMAPPED).rows)


@pytest.mark.slow
def test_offline_nn_sharded_equals_unsharded_on_four_host_devices():
    """offline-nn from the random initialisation, 3 learning rates padded to 4 on 4 devices vs the 3
    vmapped on one device: 2.3e-7 relative (measured). Not with warm_start: the ridge warm start
    (jaxcal.nn.ridge_output_layer, float32 dual solve) moves by 1e-4 relative between a batch of 1 per
    device and 3 on one device, and Adam's first steps on its near-zero output-layer gradients carry
    that to 2e-3 in the test error after training (measured at width 16-64).

    Fast cover: tests/test_sweep.py::test_sharded_equals_unsharded_on_three_host_devices (the same
    target-independent runner, jaxcal.sweep.run._run_batch: padding, mesh and gather, on online-thesis)
    """
    off = sw.SweepSpec(target="offline-nn", grid={"lr": [3e-3, 1e-2, 3e-2]}, fixed={**OFFLINE_TINY, "warm_start": False},
                       seeds=(0,))
    _close_rows(_sharded_rows(off, 4), sw.run_sweep(off).rows)


def _cli(*args, **kw):
    return subprocess.Popen([sys.executable, "-m", "jaxcal.cli", "sweep", *map(str, args)], env=_env(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kw)


@pytest.mark.parametrize(
    ("spec", "needle"),
    [
        # 4 batches of 2 (seeds 0 and 1) in two static groups; init_every=10's batches have the shape of
        # test_a_row_does_not_depend_on_the_batch_it_ran_in's batches of 2 and reuse its compiled call
        ({"grid": {"init_every": [5, 10], "w": [0.8, 0.9]}, "fixed": {"init_epochs": 50}, "seeds": [0, 1],
          "dataset": TINY_DICT, "batch_size": 2}, "Lowest gyroscope error"),
        pytest.param({"target": "offline-nn", "grid": {"warm_start": [True, False], "lr": [3e-3, 3e-2]}, "fixed": OFFLINE_TINY,
                      "seeds": [0], "batch_size": 1}, "Lowest NN test error", marks=pytest.mark.slow),
    ],
    ids=["online-thesis", "offline-nn"],
)
def test_killed_sweep_resumed_gives_the_uninterrupted_rows(tmp_path, capsys, spec, needle):
    """The run that is killed (SIGKILL once its first batch is checkpointed) is a process of its own;
    the uninterrupted run, the refusal without --resume and the resumed run are ``jaxcal.cli.main``
    in this process (the command line's own code, the same compiled calls).

    Fast cover: tests/test_sweep.py::test_killed_sweep_resumed_gives_the_uninterrupted_rows (its
    online-thesis case: the checkpoint and resume are the target-independent runner's, the same for
    offline-nn), tests/test_sweep.py::test_offline_nn_vmapped_groups_equal_each_configuration_alone
    (offline-nn rows do not depend on their batch)
    """
    cfg = tmp_path / "sweep.json"
    cfg.write_text(json.dumps(spec))
    n_batches = len(sw.plan(sw.load_sweep_spec(cfg)))
    assert n_batches == 4
    assert cli.main(["sweep", str(cfg), "--out", str(tmp_path / "full"), "--quiet"]) == 0
    assert (tmp_path / "full" / "sweep_heatmap.png").stat().st_size > 0
    assert needle in (tmp_path / "full" / "sweep.md").read_text()
    rows_full = json.loads((tmp_path / "full" / "sweep.json").read_text())["rows"]
    assert len(rows_full) == len(sw.expand(sw.load_sweep_spec(cfg)))

    killed = _cli(cfg, "--out", tmp_path / "part")
    ck = tmp_path / "part" / sw.CHECKPOINT
    t_end = time.monotonic() + 300
    while not ck.exists() and killed.poll() is None and time.monotonic() < t_end:
        time.sleep(0.01)
    killed.send_signal(signal.SIGKILL)
    killed.communicate(timeout=60)
    assert killed.returncode == -signal.SIGKILL
    n_done = len(json.loads(ck.read_text())["batches"])
    assert 1 <= n_done < n_batches and not (tmp_path / "part" / "sweep.json").exists()

    capsys.readouterr()
    # without --resume: refused (exit 2, one line), checkpoint kept
    assert cli.main(["sweep", str(cfg), "--out", str(tmp_path / "part")]) == 2
    err = capsys.readouterr().err
    assert "--resume" in err and len(err.strip().splitlines()) == 1
    assert len(json.loads(ck.read_text())["batches"]) == n_done

    assert cli.main(["sweep", str(cfg), "--out", str(tmp_path / "part"), "--resume", "--quiet"]) == 0
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
        (json.dumps({"target": "offline-nn", "grid": {"w": [0.9]}}), "unknown hyperparameter 'w' for target offline-nn"),
        (json.dumps({"target": "offline-nn", "grid": {"warm_start": [1, 0]}}), "warm_start = 1 must be true or false"),
        (json.dumps({"target": "offline-nn", "fixed": {"width": 7500.5}}), "width = 7500.5 must be an integer"),
        (json.dumps({"target": "offline-nn", "grid": {"l": [50, 2000]}}), "l = 2000 must be in [4, 1000]"),
        (json.dumps({"target": "offline-nn", "grid": {"lr": ["1e-3"]}}), "lr = '1e-3' is not a finite number"),
        (json.dumps({"target": "offline-nn", "fixed": {"lr": 0}}), "lr = 0 must be > 0"),
        (json.dumps({"target": "offline-nn", "random": {"n": 2, "params": {"width": [16, 64, "log"]}}}), "static"),
        (json.dumps({"target": "offline-nn", "dataset": {"n_train": 500}}), "no dataset settings"),
        (json.dumps({"target": "offline-nn", "grid": {"dataset.n_train": [500]}}), "no dataset settings"),
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


def test_offline_nn_schedule_study_parses_and_plans():
    spec = sw.load_sweep_spec(ROOT / "experiments" / "sweeps" / "offline_nn.json")
    assert spec.target == "offline-nn" and len(sw.expand(spec)) == 4 * 2 * 2 * 2
    batches = sw.plan(spec)
    # l and warm_start are static: four groups of 4 learning rates x 2 seeds, each one call
    assert sorted((dict(b.key)["l"], dict(b.key)["warm_start"]) for b in batches) == [
        (100, False), (100, True), (1000, False), (1000, True)]
    assert all(len(b.configs) == 8 and dict(b.key)["width"] == 7500 for b in batches)
    assert sw.spec_from_dict(sw.spec_to_dict(spec)) == spec


def test_example_config_parses():
    spec = sw.load_sweep_spec(ROOT / "docs" / "sweep_example.json")
    assert len(sw.expand(spec)) == 4 * 3 * 2 and len(sw.plan(spec)) == 3
    assert np.isclose(spec.fixed["init_epochs"], 5000)


def test_a_new_target_needs_only_a_module_and_a_registry_line(tmp_path, monkeypatch):
    """``tests/toy_sweep_target.py`` is a target (hyperparameters, batch runner, reference, report
    columns); one line registers it; then the shared spec checks, grouping, batches, report and the
    command line serve it, and its rows are its closed form and its own unvmapped reference. The
    command checks the spec once (its progress line's plan and the run take it as checked)."""
    targets.register(toy_sweep_target.TARGET)  # the one registry line
    try:
        cfg = tmp_path / "toy.json"
        cfg.write_text(json.dumps({"target": "toy-gd", "grid": {"steps": [3, 8], "lr": [0.05, 0.2, 0.45]},
                                   "seeds": [0, 1], "batch_size": 4}))
        checks = []
        check = sw_spec.check_spec
        for mod in (sw_spec, sw_plan, sw_run):  # wherever a module holds the name
            monkeypatch.setattr(mod, "check_spec", lambda s: checks.append(s.target) or check(s), raising=False)
        assert cli.main(["sweep", str(cfg), "--out", str(tmp_path / "out")]) == 0  # with progress lines
        assert checks == ["toy-gd"]
        rows = json.loads((tmp_path / "out" / "sweep.json").read_text())["rows"]
        # steps is static: two groups of 6, each cut into batches of 4 and 2
        assert [r["group"] for r in rows] == ["steps=3#0"] * 4 + ["steps=3#1"] * 2 + ["steps=8#0"] * 4 + ["steps=8#1"] * 2
        a = np.asarray(toy_sweep_target.CURVATURE)
        for r in rows:  # independent truth: x_n - c = -c (1 - lr a)^n, in float64
            want = np.linalg.norm(np.asarray(toy_sweep_target.centre(r["seed"]), np.float64) * (1 - r["lr"] * a) ** r["steps"])
            assert abs(r["error"] - want) <= 1e-5 * want, r
        spec = sw.load_sweep_spec(cfg)
        alone = [{k: r[k] for k in ("group", "steps", "lr", "seed")} | sw.run_one(spec, c)
                 for r, c in zip(rows, sw.expand(spec), strict=True)]
        _close_rows(rows, alone)
        assert "Lowest distance to the minimum" in (tmp_path / "out" / "sweep.md").read_text()
        with pytest.raises(ValueError, match=r"lr = 1.5 must be in \(0, 1\]"):  # the target's ranges, the shared check
            sw.spec_from_dict({"target": "toy-gd", "grid": {"lr": [1.5]}})
    finally:
        del targets.TARGETS["toy-gd"]
    with pytest.raises(ValueError, match="unknown target 'toy-gd'"):
        sw.spec_from_dict({"target": "toy-gd"})
