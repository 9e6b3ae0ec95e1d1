"""New parameter values never recompile (issue 20, item 1), counted with `jax.monitoring`."""

import jax.monitoring
import pytest

from forward_solver import Bay, Fabric, Parameters, Scene, solve_equilibrium
from targets import naca

_COMPILES = []


def _listen(event, duration, **kwargs):
    if event == "/jax/core/compile/backend_compile_duration":
        _COMPILES.append(kwargs.get("fun_name"))


jax.monitoring.register_event_duration_secs_listener(_listen)


@pytest.fixture(scope="module")
def first():
    """A 9x32 bay solved once ("auto"), which compiles what its solves need."""
    scene = Scene(Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=9, n_contour=32), Fabric())
    base = Parameters(pressure=1e4, prestrain_span=0.02, prestrain_chord=0.02)
    sol = solve_equilibrium(scene, base, method="auto")
    # the warm path (chord Newton) and a cold solve once, so that both are compiled
    solve_equilibrium(scene, base.replace(pressure=1.02e4), method="auto", initial=sol)
    return scene, base, sol


def test_new_values_compile_nothing(first):
    scene, base, sol = first
    before = list(_COMPILES)
    cold = solve_equilibrium(scene, base.replace(pressure=2.3e4, prestrain_span=0.015, prestrain_chord=0.025,
                                                 rib_thickness_scale=0.95), method="auto")
    warm = solve_equilibrium(scene, base.replace(pressure=1.01e4), method="auto", initial=sol)
    assert cold.converged and warm.converged
    assert "chord Newton" in warm.extra["warm_start"]  # the kept factorisation, no relaxation
    assert _COMPILES == before, f"recompiled: {_COMPILES[len(before):]}"
