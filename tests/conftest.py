"""Shared test configuration.

``JAXCAL_MARGIN_LOG=FILE`` turns on the near-threshold scan of ``tests/margins.py`` (``make margins``).

Every ``diagnose`` report the suite produces is checked against the tool's promise
(:func:`jaxcal.diagnose.report.promise_violations`: each named effect lowers the printed held-out
rms, each sensor's final held-out rms is at most its baseline's, every named estimate is plausible).
``jaxcal.diagnose.diagnose_recording`` is wrapped here, before any test module imports it, so a
test that produces a report breaking the promise fails, whatever it asserts itself.

Every annotated ``jaxcal`` function is type- and shape-checked at run time (``tests/typecheck.py``,
installed here before anything imports ``jaxcal``).

Precision is set here once: a test that needs 64-bit JAX takes the :func:`x64` fixture (as an
argument or ``@pytest.mark.usefixtures("x64")``) instead of opening ``jax.enable_x64`` itself.
"""

import functools
import gc
import os

import typecheck  # isort: skip  (before the first jaxcal import: the hook checks what is imported after it)

typecheck.install(["jaxcal"])

import jax  # noqa: E402
import margins  # noqa: E402
import pytest  # noqa: E402

import jaxcal.diagnose as _diagnose  # noqa: E402
from jaxcal.diagnose.report import promise_violations  # noqa: E402

# The CLI keeps compiled code in the user's cache folder unless told otherwise: tests never write there
# (`make test` sets JAX_COMPILATION_CACHE_DIR to the checkout's .jax_cache; a bare pytest run uses none).
if not os.environ.get("JAX_COMPILATION_CACHE_DIR"):
    os.environ.setdefault("JAXCAL_NO_CACHE", "1")

CHECKED_REPORTS = [0]


def _checked(fn):
    @functools.wraps(fn)
    def run(*args, **kwargs):
        rep = fn(*args, **kwargs)
        bad = promise_violations(rep)
        assert not bad, f"diagnose broke its promise: {bad}"
        CHECKED_REPORTS[0] += 1
        return rep

    run.__wrapped_by_promise_check__ = True
    return run


_diagnose.diagnose_recording = _checked(_diagnose.diagnose_recording)


@pytest.fixture(scope="module", autouse=True)
def _release_compiled_code():
    """Drop jax's compiled executables after each test module (:func:`jax.clear_caches`).

    Each executable XLA's CPU backend keeps alive holds about 7 memory mappings (300 small jitted
    functions: 437 -> 2449 mappings, back to 514 after clearing), and a process may hold
    ``vm.max_map_count`` (65530 by default). An xdist worker runs half the suite: one held 52853
    when its sibling died in ``tests/test_align.py``'s large diagnose compiles (SIGSEGV or SIGABRT,
    in ``backend_compile_and_load`` or ``executable.serialize()``), and xdist then waited until
    CI's limit. With the limit lowered to 6000, a loop of small jitted functions dies the same way
    at about 850 of them ("LLVM compilation error: Cannot allocate memory", SIGSEGV). A module's
    next call recompiles, or loads from the persistent cache.

    Clearing only once a worker held 30000 mappings was tried (stop 35): 2091 fewer compilations
    (8344 against 10435), yet the suite was no faster (739 s, against 731 s clearing after every
    module, both under a per-test compile probe, 2 workers on the 2-core machine), so every module
    clears.
    """
    yield
    jax.clear_caches()
    gc.collect()


@pytest.fixture
def x64():
    """Run the test with 64-bit JAX (closed-form comparisons that float32 would blur).

    Module-scoped fixtures the test uses are set up before it, so they stay in the default float32
    unless they opt in themselves. With hypothesis the context is entered once for all examples
    (intended): such tests say ``suppress_health_check=[HealthCheck.function_scoped_fixture]``.
    """
    with jax.enable_x64(True):
        yield


def pytest_configure(config):
    margins.install(config)
