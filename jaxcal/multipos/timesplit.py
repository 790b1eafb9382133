"""A held-out time split of a continuous Ferraris session, fair to a labelled tool and to multipos.

A Ferraris session (imucal's protocol) is one recording with labelled sections: the IMU resting
on each of its six faces, and three whole turns about the vertical. A labelled tool (imucal)
calibrates from the faces and the turns; multipos can also use the unlabelled motions between
the rests. To score both on data neither fitted, every static section (each face, and the
unlabelled rests just before and after each turn) is cut in two halves in time: fold 0 fits on
the first halves and scores the second, fold 1 the reverse. The motions between consecutive
static sections are left out one at a time for the gyro (:func:`gyro_folds`); a labelled tool
never uses them, so they are held out for it by construction.

:func:`time_split` builds a fold; :func:`peer_sections` gives what the labelled tool gets;
:func:`split_samples` lists the samples a multipos fold fits on and those it is scored on (the
test that the two never meet); :func:`whole_sections` is the in-sample variant (every section
whole).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from jaxcal.multipos.data import rests_around

__all__ = [
    "FERRARIS_FACES",
    "FERRARIS_TURNS",
    "TimeSplit",
    "time_split",
    "whole_sections",
    "peer_sections",
    "gyro_folds",
    "split_samples",
]

#: imucal's section names: the six faces (positive / negative axis up) and the three turns
FERRARIS_FACES = ("x_p", "x_a", "y_p", "y_a", "z_p", "z_a")
FERRARIS_TURNS = ("x_rot", "y_rot", "z_rot")


class TimeSplit(NamedTuple):
    """One fold of the time split (numpy; sample indices of one recording).

    ``statics`` (S,): names of the static sections in time order (faces by their label, rests as
    ``"{turn}_before"`` / ``"{turn}_after"``); ``is_face`` (S,); ``fit_iv`` / ``score_iv`` (S, 2):
    the ``[start, stop)`` half fitted / scored; ``spans`` (S - 1, 2): ``[a, b]`` from the end of
    static section ``j`` to the start of ``j + 1`` (the motion between them); ``across_turn``
    (S - 1,): that span holds a turn (it is the turn, not a motion between poses); ``turns``
    (K, 2): ``[a, b]`` of each labelled turn; ``rest_idx`` (K, 2): the static sections just before
    and after each turn (indices into ``statics``); :attr:`turn_rests` their fitted halves."""

    statics: tuple
    is_face: np.ndarray
    fit_iv: np.ndarray
    score_iv: np.ndarray
    spans: np.ndarray
    across_turn: np.ndarray
    turns: np.ndarray
    rest_idx: np.ndarray

    @property
    def turn_rests(self) -> list:
        """Per turn, the fitted halves of its rests as ``[start, stop)`` pairs: the windows its axis
        is read from (:func:`~jaxcal.multipos.prepare_turns`)."""
        return [[tuple(int(x) for x in self.fit_iv[i]) for i in row] for row in self.rest_idx]


def time_split(bounds: dict, fold: int, faces: Sequence[str] = FERRARIS_FACES, turns: Sequence[str] = FERRARIS_TURNS,
               rest_n: int = 200, rest_gap: int = 10) -> TimeSplit:
    """Fold ``fold`` (0 or 1) of the time split of a Ferraris session with labelled sections
    ``bounds[name] = (start, end)`` (end exclusive). The rests next to each turn are ``rest_n``
    samples starting ``rest_gap`` samples from it (their mean gravity is the turning axis of a
    turn about the vertical).

    Args:
        bounds: section name -> ``(start, end)`` sample indices (end exclusive).
        fold: 0 (fit the first halves, score the second) or 1 (the reverse).
        faces: names of the face sections.
        turns: names of the turn sections.
        rest_n: samples in each rest window next to a turn.
        rest_gap: samples between a turn and its rest windows.
    """
    if fold not in (0, 1):
        raise ValueError(f"fold must be 0 or 1, got {fold!r}")
    missing = [n for n in (*faces, *turns) if n not in bounds]
    if missing:
        raise ValueError(f"bounds: no section named {missing} (have {sorted(bounds)})")
    tspans = [(bounds[n][0], bounds[n][1] - 1) for n in turns]
    statics = [(n, *bounds[n]) for n in faces]
    statics += [(f"{n}_{w}", a, b) for n, win in zip(turns, rests_around(tspans, rest_n, rest_gap))
                for w, (a, b) in zip(("before", "after"), win)]
    statics.sort(key=lambda x: x[1])
    fit_iv, score_iv = [], []
    for _, a, b in statics:
        m = (a + b) // 2
        halves = [(a, m), (m, b)]
        fit_iv.append(halves[fold])
        score_iv.append(halves[1 - fold])
    spans = [(statics[j][2], statics[j + 1][1] - 1) for j in range(len(statics) - 1)]
    across = [any(a <= ta and tb <= b for ta, tb in tspans) for a, b in spans]
    names = tuple(x[0] for x in statics)
    rest_idx = [[names.index(f"{n}_{w}") for w in ("before", "after")] for n in turns]
    return TimeSplit(names, np.array([n in faces for n in names]), np.array(fit_iv), np.array(score_iv),
                     np.array(spans), np.array(across), np.array(tspans), np.array(rest_idx))


def whole_sections(split: TimeSplit) -> TimeSplit:
    """The same sections whole (fitted and scored on all of each static section): in-sample."""
    whole = np.concatenate([np.minimum(split.fit_iv[:, :1], split.score_iv[:, :1]),
                            np.maximum(split.fit_iv[:, 1:], split.score_iv[:, 1:])], 1)
    return split._replace(fit_iv=whole, score_iv=whole)


def peer_sections(split: TimeSplit, bounds: dict, faces: Sequence[str] = FERRARIS_FACES,
                  turns: Sequence[str] = FERRARIS_TURNS) -> dict:
    """The sections a labelled Ferraris tool gets on a fold: the faces' fitted halves, the whole
    turns (it needs all three), as ``{name: (start, end)}``.

    Args:
        split: the fold (:func:`time_split`).
        bounds: section name -> ``(start, end)`` sample indices, as for :func:`time_split`.
        faces: names of the face sections.
        turns: names of the turn sections.
    """
    return ({n: tuple(int(x) for x in split.fit_iv[split.statics.index(n)]) for n in faces}
            | {n: tuple(int(x) for x in bounds[n]) for n in turns})


def gyro_folds(across_turn: np.ndarray, n_turns: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gyro folds: one row per motion between poses (spans not ``across_turn``) leaving that motion
    out (every turn used), then one row per turn leaving it out (every motion used); spans across a
    turn have weight 0 everywhere. Returns ``(gyr_w, turn_w, scored)``: ``scored[i]`` is the span
    row ``i`` leaves out (-1 for the turn rows).

    Args:
        across_turn: (S - 1,) bool per span, True where it holds a turn (:attr:`TimeSplit.across_turn`).
        n_turns: number of turns.
    """
    motions = np.flatnonzero(~np.asarray(across_turn))
    M = len(motions)
    gw = np.tile((~np.asarray(across_turn)).astype(float), (M + n_turns, 1))
    kw = np.ones((M + n_turns, n_turns))
    gw[np.arange(M), motions] = 0.0
    kw[M + np.arange(n_turns), np.arange(n_turns)] = 0.0
    return gw, kw, np.concatenate([motions, -np.ones(n_turns, int)])


def split_samples(split: TimeSplit, gw_row: np.ndarray, kw_row: np.ndarray, use_turns: bool = True) -> tuple[set, set, set]:
    """Sample indices a multipos fold fits on (acc and gyro), and those it is scored on:
    ``(fitted, acc_scored, gyr_scored)``. A span ``[a, b]`` uses samples ``a .. b`` (midpoint
    rates); the rests next to a turn give its axis (their fitted halves, in ``fit_iv``).

    Args:
        split: the fold (:func:`time_split`).
        gw_row: (S - 1,) one row of ``gyr_w`` (:func:`gyro_folds`).
        kw_row: (K,) the matching row of ``turn_w``.
        use_turns: the fold fits the turns (their samples count as fitted).
    """
    rng = lambda a, b: set(range(int(a), int(b)))  # noqa: E731
    fitted = set().union(*(rng(a, b) for a, b in split.fit_iv))
    fitted |= set().union(set(), *(rng(a, b + 1) for (a, b), w in zip(split.spans, gw_row) if w > 0))
    if use_turns:
        fitted |= set().union(*(rng(a, b + 1) for (a, b), w in zip(split.turns, kw_row) if w > 0))
    acc_scored = set().union(*(rng(a, b) for (a, b), face in zip(split.score_iv, split.is_face) if face))
    gyr_scored = set().union(set(), *(rng(a, b + 1) for (a, b), w, x in zip(split.spans, gw_row, split.across_turn)
                                      if w == 0 and not x))
    gyr_scored |= set().union(set(), *(rng(a, b + 1) for (a, b), w in zip(split.turns, kw_row) if w == 0))
    return fitted, acc_scored, gyr_scored
