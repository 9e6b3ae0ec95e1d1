"""New parameter values never recompile, counted with `jax.monitoring`."""

import os

import jax.monitoring
import numpy as np
import pytest

from forward_solver import Parameters, solve_equilibrium
from targets import naca
from support.solver import default_bay, default_scene

_COMPILES = []


def _listen(event, duration, **kwargs):
    if event == "/jax/core/compile/backend_compile_duration":
        _COMPILES.append(kwargs.get("fun_name"))


jax.monitoring.register_event_duration_secs_listener(_listen)


@pytest.fixture(scope="module")
def first():
    """A 9x32 bay solved once ("auto"), which compiles what its solves need."""
    scene = default_scene(9, 32)
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


def test_a_bay_of_another_chord_measures_without_compiling(first):
    """The design measures every bay of a wing (and, under ``jax.jacfwd``, its tangents) with one
    program: a chord is an operand, not a static argument (the 40-cell wing compiled the section
    program 80 times, 28 of its 66 design seconds)."""
    import jax
    import jax.numpy as jnp

    from inverse_design.objectives import bay_distances

    scene, _, sol = first
    etas, target = (0.0, 0.5, 1.0), naca("2412")
    with jax.enable_x64(True):
        nodes = jnp.asarray(sol.nodes)

        def both(scale, chord):
            d = bay_distances(nodes * scale, [target] * 3, etas, [chord] * 3)
            return d, jax.jacfwd(lambda s: bay_distances(nodes * s, [target] * 3, etas, [chord] * 3))(scale)

        d1, j1 = both(1.0, 1.0)
        before = list(_COMPILES)
        d2, j2 = both(0.8, 0.8)  # the same bay scaled by 0.8 and measured at chord 0.8: the same section
    assert _COMPILES == before, f"recompiled: {_COMPILES[len(before):]}"
    d1, d2, j1, j2 = (np.asarray(a) for a in (d1, d2, j1, j2))  # compared in float64, outside the scope
    assert np.max(np.abs(d2 - d1)) < 1e-12
    assert np.max(np.abs(j2 * 0.8 - j1)) < 1e-12  # d/ds at 0.8 of (nodes s / 0.8) = nodes / 0.8


def test_a_derivative_reuses_the_plain_solves_programs(first):
    """Under ``jax.grad`` the host solve runs at top level (`adjoint.differentiable_solution`): its
    relaxation, Newton and Jacobian programs are the plain solve's, not a second, transformed copy
    (before: relax_jit, prepare and static_state compiled again in every design)."""
    import jax
    import jax.numpy as jnp

    scene, base, _ = first
    with jax.enable_x64(True):
        resolved = base.resolved(scene.fabric)

        def peak(pressure):
            return jnp.max(solve_equilibrium(scene, resolved.replace(pressure=pressure), method="auto").nodes[..., 2])

        before = list(_COMPILES)
        slope = jax.grad(peak)(jnp.float64(1.5e4))
    new = _COMPILES[len(before):]
    assert np.isfinite(float(slope)) and float(slope) > 0.0  # more pressure, more bulge
    again = [name for name in new if name in ("jit(relax_jit)", "jit(prepare)", "jit(_jacobian_values)")]
    assert not again, f"the derivative compiled the solve again: {again}"


def test_fast_compilation_adds_its_flags_once_and_never_overrides_the_callers(monkeypatch):
    from forward_solver.compilation import xla

    monkeypatch.setattr(xla, "_backend_started", lambda: False)
    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/tmp/x")
    assert xla.enable_fast_compilation()
    assert os.environ["XLA_FLAGS"] == "--xla_dump_to=/tmp/x " + " ".join(xla.FAST_COMPILATION_FLAGS)
    assert not xla.enable_fast_compilation()  # named already: unchanged
    assert os.environ["XLA_FLAGS"].count("fusion_emitters") == 1
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=true")  # the caller's own choice
    assert not xla.enable_fast_compilation() and os.environ["XLA_FLAGS"] == "--xla_cpu_use_fusion_emitters=true"
    monkeypatch.delenv("XLA_FLAGS")
    monkeypatch.setattr(xla, "_backend_started", lambda: True)  # XLA has read its flags: nothing to add
    assert not xla.enable_fast_compilation() and "XLA_FLAGS" not in os.environ


def test_the_command_runs_with_the_fast_flags_and_gives_the_environment_back(monkeypatch):
    from forward_solver.compilation import xla
    from inverse_design.app import cli

    from inverse_design.app.options import InputError

    seen = []

    def check_platform():  # (the run's first step after its flags are set: stop there)
        seen.append(os.environ.get("XLA_FLAGS"))
        raise InputError("enough")

    monkeypatch.setattr(xla, "_backend_started", lambda: False)
    monkeypatch.setattr(cli, "check_platform", check_platform)
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    assert cli.main(["--quiet"]) == 2
    assert seen == [" ".join(xla.FAST_COMPILATION_FLAGS)] and "XLA_FLAGS" not in os.environ
    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/tmp/x")
    assert cli.main(["--quiet"]) == 2
    assert seen[-1] == "--xla_dump_to=/tmp/x " + " ".join(xla.FAST_COMPILATION_FLAGS)
    assert os.environ["XLA_FLAGS"] == "--xla_dump_to=/tmp/x"


def test_a_cold_solve_compiles_its_finer_levels_and_newton_ahead():
    """`forward_solver.compilation.Ahead`: the coarsest relaxation compiles on the caller's thread while the
    finer level and Newton's programs compile on the worker; each is compiled once (a 9x48 bay:
    levels 5x24 and 9x48, shapes no other test of this module solves)."""
    import threading

    from forward_solver import compilation as ahead

    threads = []

    def listen(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            threads.append((kwargs.get("fun_name"), threading.current_thread().name))

    jax.monitoring.register_event_duration_secs_listener(listen)
    previous = ahead.set_compile_ahead(True)
    try:
        scene = default_scene(9, 48)
        sol = solve_equilibrium(scene, Parameters(pressure=1e4, prestrain_span=0.02, prestrain_chord=0.02),
                                method="relax+newton")
    finally:
        ahead.set_compile_ahead(previous)
        jax.monitoring.unregister_event_duration_listener(listen)
    assert sol.converged and [level["shape"] for level in sol.extra["levels"]] == [(5, 24)]
    relax = [name for fun, name in threads if fun == "jit(relax_jit)"]
    assert len(relax) == 2 and relax.count("MainThread") == 1, threads
    worker = {fun for fun, name in threads if name.startswith("compile-ahead")}
    assert {"jit(relax_jit)", "jit(static_state)", "jit(_jacobian_values)"} <= worker, threads
    main = [fun for fun, name in threads if name == "MainThread"]
    assert "jit(static_state)" not in main and "jit(_jacobian_values)" not in main, threads


def test_a_forward_only_derivative_compiles_its_right_hand_sides_ahead():
    """Within ``forward_only(n)`` a cold solve compiles the batched right-hand sides of its ``n``
    tangents (`implicit.batched_rhs_task`) on the worker, and the derivative takes that program
    (no compilation of it on the caller's thread); its Jacobian is the transposable one's to
    rounding (a 9x40 bay, a grid no other test solves)."""
    import threading

    import jax.numpy as jnp

    from forward_solver import compilation as ahead
    from forward_solver.derivatives.implicit import forward_only

    threads = []

    def listen(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            threads.append((kwargs.get("fun_name"), threading.current_thread().name))

    scene = default_scene(9, 40)
    weights = np.random.default_rng(1).normal(size=(9, 40, 3))

    def loss(q):
        parameters = Parameters(pressure=q[0], prestrain_span=q[1], prestrain_chord=0.02)
        return jnp.sum(weights * solve_equilibrium(scene, parameters, method="relax+newton").nodes)

    q = np.array([1e4, 0.02])
    jax.monitoring.register_event_duration_secs_listener(listen)
    previous = ahead.set_compile_ahead(True)
    try:
        with jax.enable_x64(True), forward_only(q.size):
            direct = np.asarray(jax.jacfwd(loss)(jnp.asarray(q)))
    finally:
        ahead.set_compile_ahead(previous)
        jax.monitoring.unregister_event_duration_listener(listen)
    with jax.enable_x64(True):
        transposable = np.asarray(jax.jacfwd(loss)(jnp.asarray(q)))
    rhs = [name for fun, name in threads if fun == "jit(batched_rhs)"]
    assert rhs and all(name.startswith("compile-ahead") for name in rhs), threads
    np.testing.assert_allclose(direct, transposable, rtol=1e-9)


def test_a_bays_geometry_is_made_once_per_float64_setting_and_never_kept_from_a_trace():
    import jax.numpy as jnp

    bay = default_bay(5, 16)
    with jax.enable_x64(True):
        traced = jax.jit(lambda x: x * bay.geometry().chord_root)(jnp.ones(()))  # made inside a trace
        made = bay.geometry()
        assert not any(isinstance(a, jax.core.Tracer) for a in made)
        assert bay.geometry() is made and made.contour_root.dtype == np.float64
        assert float(traced) == 1.0
    single = bay.geometry()
    assert single is not made and single.contour_root.dtype == np.float32


def test_compiling_ahead_cancels_what_has_not_begun_and_drops_a_failing_task():
    import concurrent.futures
    import threading

    from forward_solver import compilation as ahead

    previous = ahead.set_compile_ahead(True)
    started, gate, ran = threading.Event(), threading.Event(), []
    try:
        with ahead.Ahead() as a:
            a.submit(("test", "busy"), lambda: started.set() or gate.wait())  # holds the single worker
            started.wait()
            later = a.submit(("test", "later"), lambda: ran.append("later"))
            assert a.submit(("test", "later"), lambda: ran.append("twice")) is None  # one per key
            a.ready(later)  # not begun: cancelled, left to the caller
            assert later[1].cancelled()
            again = a.submit(("test", "later"), lambda: ran.append("again"))  # and may be submitted again
            failing = a.submit(("test", "failing"), lambda: 1 / 0)
            gate.set()
            concurrent.futures.wait([again[1], failing[1]])
            # the error is dropped: the caller meets it when it does the work itself
            assert again[1].result() is True and failing[1].result() is False
        assert ran == ["again"]
        ahead.set_compile_ahead(False)
        assert ahead.Ahead().submit(("test", "off"), lambda: None) is None
    finally:
        gate.set()
        ahead.set_compile_ahead(previous)


def test_device_arrays_sends_the_same_concrete_values_once_and_keeps_nothing_from_a_trace():
    """`precision.device_arrays` gives the arrays it sent for the same concrete values again (the same
    objects), new ones for other values or another float64 setting, and within ``jax.jit`` the trace's
    own values: a kept array is never a tracer, and one made in a trace is never kept."""
    import jax.numpy as jnp

    from forward_solver.precision import device_arrays

    values = [np.float64(2.5e4), np.float64(0.013), np.arange(6.0)]
    with jax.enable_x64(True):
        first = device_arrays(values, np.float64)
        again = device_arrays([np.float64(2.5e4), np.float64(0.013), np.arange(6.0)], np.float64)
        assert all(a is b for a, b in zip(first, again))
        other = device_arrays([np.float64(2.5e4), np.float64(0.014), np.arange(6.0)], np.float64)
        assert other[1] is not first[1] and float(other[1]) == 0.014
        traced = jax.jit(lambda x: x * device_arrays([np.float64(7.25)], np.float64)[0])(jnp.ones(()))
        made = device_arrays([np.float64(7.25)], np.float64)
        assert not isinstance(made[0], jax.core.Tracer) and float(traced) == 7.25
        inside = jax.jit(lambda x: x + sum(isinstance(a, jax.core.Tracer) for a in device_arrays(values, np.float64)))
        assert float(inside(jnp.zeros(()))) == 3.0  # (kept arrays are not handed into a trace)
    with jax.enable_x64(False):
        narrow = device_arrays(values, np.float64)
        assert narrow[0] is not first[0] and narrow[0].dtype == np.float32
