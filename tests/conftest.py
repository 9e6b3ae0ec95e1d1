"""Shared fixtures.

JAX compilation dominates small tests, so tests reuse a few grid shapes and
module- or session-scoped solutions. Tests that call kernels directly run
inside ``jax.enable_x64(True)`` through the ``x64`` fixture; the public API
enters it by itself.
"""

import jax
import pytest


@pytest.fixture
def x64():
    with jax.enable_x64(True):
        yield


def pytest_configure(config):
    config.addinivalue_line(
        "markers", "notebooks: executes the study notebooks in notebooks/ in their small mode "
        "(a few minutes); deselect with -m 'not notebooks'")
