"""Precision as a boundary: :func:`float64`, the one way a public entry point enters float64.

JAX computes in float32 unless ``jax_enable_x64`` is on. jaxcal never turns it on globally: an
entry point that needs float64 (raw counts ~1e4 LSB with 1e-5 relative floors, multipos, the
``online`` filter, diagnose, the scorers of :mod:`jaxcal.eval`) is decorated with
:func:`float64`, which runs it inside ``jax.enable_x64(True)``, so a caller never has to. The
kernels below those entry points (:mod:`jaxcal.rotation`, :mod:`jaxcal.sensor`, the filter, the
multipos residuals) are dtype-polymorphic: they follow their inputs' dtype and enter no context
themselves. Followed:

- optimistix (``optimistix/_misc.py``: ``tree_dtype``, ``inexact_asarray``): a solver computes in
  ``jnp.result_type`` of its inputs and falls back to the default float only for integer input;
  our kernels do the same, and the precision is chosen once, where arrays enter.
- optax (``optax/_src/float64_test.py``): one test parameterised over the public transformations
  checks that float64 in gives float64 out under x64; ``tests/test_precision.py`` does the same
  over jaxcal's kernels, with float32 in giving float32 out.

What stays float32, explicitly: the thesis's chapter-3 and chapter-4 neural-network paths
(:mod:`jaxcal.nn`, :mod:`jaxcal.offline`, :mod:`jaxcal.online_thesis`, the ``nn`` and
``online-thesis`` methods) run as published, in float32; they carry no :func:`float64`, and
``tests/test_precision.py`` checks that they return float32. The multi-pose simulator
(:mod:`jaxcal.simulate.multipos`) draws its random rotations inside ``jax.enable_x64(False)``
so that a session is the same whether or not its caller is in float64.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

import jax

__all__ = ["float64"]

F = TypeVar("F", bound=Callable[..., Any])


def float64(fn: F) -> F:
    """Run ``fn`` inside ``jax.enable_x64(True)`` (restored on return), keeping its name,
    docstring and signature (:func:`functools.wraps`).

    Arrays created inside are float64 by default; a kernel called from inside follows the dtype
    of what it is given. Nested use is harmless (the context is re-entrant).

    Args:
        fn: a public entry point whose arithmetic must be float64.
    """

    @functools.wraps(fn)
    def wrapped(*args: Any, **kwargs: Any) -> Any:
        with jax.enable_x64(True):
            return fn(*args, **kwargs)

    return wrapped  # type: ignore[return-value]
