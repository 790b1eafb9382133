"""Evaluation of calibrations on real recordings: library code the experiments only compose.

- :mod:`~jaxcal.eval.scores`: scores of a :class:`~jaxcal.sensor.LinearCal` pair on static poses
  (``| |f| - 1 g |``) and on the motions between them (carried-gravity angle), in-sample and
  leave-poses-out, as summary rows; paired comparison of rows with a peer's.
- :mod:`~jaxcal.eval.heldout`: held-out fold runners: ``online`` on pose folds, any per-fold
  calibrations scored on what their fold left out (:func:`~jaxcal.eval.heldout.fold_errors`),
  multipos and fixed calibrations on a time split of a continuous session (fair to peers that need
  whole sections).
- :mod:`~jaxcal.eval.seqsplit`: a recording with ``seq`` ids scored by each sequence's first and
  last samples, in-sample and on a time split of its sequences.
- :mod:`~jaxcal.eval.checks`: independent checks: rotation carried by the integrated gyro between two
  rests (the 90 deg turn of a rot90x recording, the return to the start pose of a hand-held one).
- :mod:`~jaxcal.eval.mocap`: a recording against its motion capture (``diagnose``'s held-out RMS beside
  the recording as its maker calibrated it).
- :mod:`~jaxcal.eval.transfer`: a model's applied output scored on another recording against every
  truth it carries (labels, sequence ends, rests, mocap): ``jaxcal score``.
- :mod:`~jaxcal.eval.peers`: peers' and published calibrations converted to ``LinearCal``.

No I/O: every function takes arrays (or a :class:`~jaxcal.recording.Recording`) and returns arrays
or plain dicts.
"""

from jaxcal.eval import checks, heldout, mocap, peers, scores, seqsplit, transfer

__all__ = ["checks", "heldout", "mocap", "peers", "scores", "seqsplit", "transfer"]
