"""Simulated datasets as :class:`~jaxcal.recording.Recording` objects (what ``jaxcal simulate``
writes, and the small recordings the method contract test fits).

* :func:`dataset2_recordings`: thesis Dataset 2 (section 4.2), rotation sequences + test sets.
* :func:`dataset1_recordings`: the Dataset 1 surrogate (section 3.4), labelled static poses.
* :func:`multipos_recording`: static poses joined by constant-rate rotations (``multipos``;
  :mod:`jaxcal.simulate.multipos`).
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np
from flax import serialization

from jaxcal.recording import Recording
from jaxcal.simulate.dataset1 import dataset1
from jaxcal.simulate.dataset2 import Dataset2Config, dataset2_jit
from jaxcal.simulate.multipos import simulate_poses

__all__ = ["dataset1_recordings", "dataset2_recordings", "multipos_recording"]


def dataset2_recordings(seed: int, config: Dataset2Config = Dataset2Config(),
                        labels: bool = False) -> tuple[dict[str, Recording], dict[str, Any]]:
    """Dataset 2 as recordings: ``train``/``val`` (sequences concatenated), ``test_acc``,
    ``test_gyr``; and the hidden truth (JSON-able).

    ``train``/``val`` hold raw ``acc``/``gyr`` (LSB), ``seq`` ids, ``static`` at both ends of every
    sequence (eq. 4.4) and the datasheet metadata; the test sets hold labels.

    Args:
        seed: PRNG seed of :func:`~jaxcal.simulate.dataset2`.
        config: the dataset's configuration (static).
        labels: also store ``acc_ref``/``gyr_ref`` in ``train`` and ``val``.
    """
    ds = dataset2_jit(jax.random.PRNGKey(seed), config)  # one compile (cached)
    fs = float(config.fs)
    spec = dict(
        fs=fs,
        acc_lsb_per_g=np.asarray(config.acc_lsb_per_g, np.float64),
        acc_bias_lsb=np.asarray(0.0),
        gyr_lsb_per_rads=np.asarray(config.gyr_lsb_per_rads, np.float64),
        gyr_bias_lsb=np.asarray(0.0),
    )

    def raw(a: Any) -> np.ndarray:
        a = np.asarray(a)
        return a.astype(np.int32) if config.round_counts else a.astype(np.float64)

    def sequences(s: Any) -> Recording:
        m, n = s.acc.shape[:2]
        seq = np.repeat(np.arange(m), n)
        static = np.zeros((m, n), dtype=bool)
        static[:, 0] = static[:, -1] = True  # eq. 4.4: the rate is zero at both ends
        kw: dict[str, Any] = {}
        if labels:
            kw = dict(
                acc_ref=np.asarray(s.acc_true, np.float64).reshape(-1, 3),
                gyr_ref=np.asarray(s.gyr_true, np.float64).reshape(-1, 3),
            )
        return Recording(
            t=np.arange(m * n) / fs,
            acc=raw(s.acc).reshape(-1, 3),
            gyr=raw(s.gyr).reshape(-1, 3),
            seq=seq,
            static=static.reshape(-1),
            **kw,
            **spec,
        )

    n_acc = ds.test_acc.raw.shape[0]
    test_acc = Recording(
        t=np.arange(n_acc) / fs,
        acc=raw(ds.test_acc.raw),
        acc_ref=np.asarray(ds.test_acc.true, np.float64),
        static=np.ones(n_acc, dtype=bool),
        **spec,
    )
    n_gyr = ds.test_gyr.raw.shape[0]
    test_gyr = Recording(
        t=np.linspace(0.0, 2.0 * np.pi, n_gyr),  # eq. 4.7: w(t) = 0.35 sin(t), t in [0, 2 pi]
        gyr=raw(ds.test_gyr.raw),
        gyr_ref=np.asarray(ds.test_gyr.true, np.float64),
        **(spec | {"fs": None}),  # its t does not step at the sequences' fs
    )
    truth = {
        "dataset": "dataset2",
        "seed": seed,
        "config": {k: (float(v) if isinstance(v, float) else v) for k, v in config._asdict().items()},
        "acc_true": {"s": np.asarray(ds.acc_true_model.s).tolist(), "b": np.asarray(ds.acc_true_model.b).tolist()},
        "gyr_true": {"s": np.asarray(ds.gyr_true_model.s).tolist(), "b": np.asarray(ds.gyr_true_model.b).tolist()},
        "model": "y = round(s * x + b) per axis (LSB), x in g / rad/s (thesis eq. 4.6)",
    }
    recs = {"train": sequences(ds.train), "val": sequences(ds.val), "test_acc": test_acc, "test_gyr": test_gyr}
    return recs, truth


def dataset1_recordings(seed: int) -> tuple[dict[str, Recording], dict[str, Any]]:
    """Dataset 1 surrogate as recordings: ``train``/``val``/``test`` static poses; and the truth.

    Each split holds ``acc`` (LSB), ``acc_ref`` (the robot's labels, g), ``static`` (all true)
    and the extra key ``acc_true`` (the exact specific force, for scoring); ``t`` is the pose
    index in seconds (the poses are independent).

    Args:
        seed: PRNG seed of :func:`~jaxcal.simulate.dataset1`.
    """
    ds = dataset1(jax.random.PRNGKey(seed))
    spec = ds.spec
    recs: dict[str, Recording] = {}
    for split in ("train", "val", "test"):
        part = getattr(ds, split)
        n = part.acc.shape[0]
        recs[split] = Recording(
            t=np.arange(n, dtype=np.float64),
            acc=np.asarray(part.acc, np.float64),
            acc_ref=np.asarray(part.acc_ref, np.float64),
            static=np.ones(n, dtype=bool),
            acc_lsb_per_g=np.asarray(spec.s, np.float64),
            acc_bias_lsb=np.asarray(spec.b, np.float64),
            extra={"acc_true": np.asarray(part.acc_true, np.float64)},
        )
    model = jax.tree.map(lambda a: np.asarray(a).tolist(), serialization.to_state_dict(ds.model))
    truth = {"dataset": "dataset1", "seed": seed, "model": model}
    return recs, truth


def multipos_recording(key: jax.Array, **kwargs: Any) -> Recording:
    """:func:`~jaxcal.simulate.multipos.simulate_poses` as a raw recording (``t``, ``acc``,
    ``gyr`` in LSB; no labels, no datasheet values).

    Args:
        key: PRNG key of the random poses.
        **kwargs: the other arguments of :func:`~jaxcal.simulate.multipos.simulate_poses`
            (``n_poses``, ``acc_cal``, ``gyr_cal``, ``fs``, ...).
    """
    t, acc, gyr = simulate_poses(key, **kwargs)
    return Recording(t=t, acc=acc, gyr=gyr)
