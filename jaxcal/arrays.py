"""The array type of jaxcal's shape annotations, and the glossary of their dimension letters.

Library functions accept numpy arrays as well as JAX arrays (and tracers inside ``jit``/``vmap``),
so annotations are written ``Float[Array, "N 3"]`` with :data:`Array` = ``jax.Array | np.ndarray``.
The test suite checks every annotation at run time (``tests/typecheck.py``: jaxtyping + beartype).
A single dimension is written with a leading space (``" N"``) so linters do not read it as a name.
Dimension letters are listed in ARCHITECTURE.md ("Dimension letters").
"""

from __future__ import annotations

import jax
import numpy as np

__all__ = ["Array"]

Array = jax.Array | np.ndarray
"""A JAX array, tracer or numpy array."""
