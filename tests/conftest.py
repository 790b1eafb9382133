"""Shared test configuration.

``JAXCAL_MARGIN_LOG=FILE`` turns on the near-threshold scan of ``tests/margins.py`` (``make margins``).
"""

import margins


def pytest_configure(config):
    margins.install(config)
