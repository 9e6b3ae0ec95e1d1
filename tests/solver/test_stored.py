"""The program store (`forward_solver.compilation`, `stored_jit`): the same results, and a second process neither traces
nor lowers a stored program."""

import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from forward_solver import compilation as store
from support.command import TEST_XLA_FLAGS, environment

TRACES = []


def _program():
    """A small program with an array, a pair (a pytree), a Python float and a static argument: a new
    function object each time (JAX keeps one process's traces by the function), under one name (the
    store's)."""

    def scaled(x, pair, scale, power):
        TRACES.append(power)  # (runs when the function is traced, not when its program runs)
        return {"value": jnp.sum(x**power) * scale + pair[0], "twice": 2.0 * pair[1]}

    scaled.__qualname__ = "scaled"
    return scaled


def _stored():
    return store.stored_jit(_program(), static_argnames=("power",))


@pytest.fixture
def folder(tmp_path):
    previous = store.use_program_store(tmp_path)
    yield tmp_path
    store.use_program_store(previous)


def _call(function, power=2):
    with jax.enable_x64(True):
        x = jnp.linspace(0.0, 1.0, 7)
        return function(x, (jnp.float64(0.5), jnp.arange(3.0)), 1.5, power=power)


def test_a_second_process_loads_without_tracing(folder):
    plain = _call(jax.jit(_program(), static_argnames=("power",)))
    first = _stored()
    TRACES.clear()
    once = _call(first)
    assert TRACES == [2]  # exported once
    assert len(list(folder.glob("scaled-*.bin"))) == 1
    _call(first)
    assert TRACES == [2]  # the process's own program
    later = _stored()  # as in a new process: nothing in memory
    again = _call(later)
    assert TRACES == [2]  # loaded from the file, not traced
    for result in (once, again):
        assert set(result) == {"value", "twice"}
        np.testing.assert_array_equal(np.asarray(result["value"]), np.asarray(plain["value"]))
        np.testing.assert_array_equal(np.asarray(result["twice"]), np.asarray(plain["twice"]))
    _call(later, power=3)  # another static value: another program, another file
    assert TRACES == [2, 3] and len(list(folder.glob("scaled-*.bin"))) == 2


def test_a_broken_entry_is_exported_again(folder):
    _call(_stored())
    (path,) = folder.glob("scaled-*.bin")
    path.write_bytes(b"half a file")
    TRACES.clear()
    result = _call(_stored())
    assert TRACES == [2]
    assert float(result["value"]) == pytest.approx(1.5 * np.sum(np.linspace(0.0, 1.0, 7) ** 2) + 0.5, rel=1e-15)
    assert path.read_bytes() != b"half a file"


def test_tracers_and_no_store_run_jitted(tmp_path):
    function = _stored()
    previous = store.use_program_store(None)
    try:
        _call(function)
        assert not list(tmp_path.iterdir())
        store.use_program_store(tmp_path)
        with jax.enable_x64(True):
            x = jnp.linspace(0.0, 1.0, 7)
            grad = jax.grad(lambda x: function(x, (0.5, jnp.arange(3.0)), 1.5, power=2)["value"])(x)
            batched = jax.vmap(lambda s: function(x, (0.5, jnp.arange(3.0)), s, power=2)["value"])(jnp.arange(3.0))
        x = np.linspace(0.0, 1.0, 7)
        np.testing.assert_allclose(grad, 3.0 * x, rtol=1e-15)
        np.testing.assert_allclose(batched, np.arange(3.0) * np.sum(x**2) + 0.5, rtol=1e-15)
        assert not list(tmp_path.iterdir())  # (only concrete calls are stored)
    finally:
        store.use_program_store(previous)


@pytest.mark.parametrize("loop", [False, True])
def test_a_light_program_compiles_light_only_at_the_top_level(tmp_path, loop):
    """A ``light`` program's top-level calls ask its rule (by the arguments' shapes) and run the
    light compilation, with and without a store, and a ``loop`` program's other top-level calls
    `LOOP_OPTIONS`; under ``jit``, ``vmap`` and ``grad`` it is part of the caller's program (JAX
    refuses compiler options there: a ValueError) and the rule is not asked. Every result is the
    plain program's to rounding."""
    asked = []

    def light(x, **_):
        asked.append(x.shape)
        return x.shape[0] <= 7

    function = store.stored_jit(_program(), static_argnames=("power",), light=light, loop=loop)
    plain = jax.jit(_program(), static_argnames=("power",))
    previous = store.use_program_store(None)
    try:
        for folder in (None, tmp_path):
            store.use_program_store(folder)
            asked.clear()
            for n in (7, 9):  # light, then not
                with jax.enable_x64(True):
                    x = jnp.linspace(0.0, 1.0, n)
                    got, want = (f(x, (0.5, jnp.arange(3.0)), 1.5, power=2)["value"] for f in (function, plain))
                np.testing.assert_allclose(got, want, rtol=1e-14)
            assert asked == [(7,), (9,)]
            asked.clear()
            with jax.enable_x64(True):
                x = jnp.linspace(0.0, 1.0, 7)
                grad = jax.grad(lambda x: function(x, (0.5, jnp.arange(3.0)), 1.5, power=2)["value"])(x)
                inner = jax.jit(lambda x: function(x, (0.5, jnp.arange(3.0)), 1.5, power=2)["value"])(x)
                batched = jax.vmap(lambda s: function(x, (0.5, jnp.arange(3.0)), s, power=2)["value"])(jnp.arange(3.0))
            np.testing.assert_allclose(grad, 3.0 * np.asarray(x), rtol=1e-15)
            np.testing.assert_allclose(inner, 1.5 * np.sum(np.asarray(x) ** 2) + 0.5, rtol=1e-15)
            np.testing.assert_allclose(batched, np.arange(3.0) * np.sum(np.asarray(x) ** 2) + 0.5, rtol=1e-15)
            assert asked == []
        assert len(list(tmp_path.glob("scaled-*.bin"))) == 2  # (one program a shape, light or not)
    finally:
        store.use_program_store(previous)


#: The solve of `test_a_solve_is_the_same_with_the_store`, in a process of its own.
_SAME_SOLVE = r"""
import sys
from pathlib import Path
import numpy as np
from forward_solver import Bay, Fabric, Parameters, Scene, solve_equilibrium
from forward_solver import compilation as store
from forward_solver.solvers import relax
from targets import naca

relax.LIGHT_RELAX_NODES = 0  # (every program at LLVM's level 2: see the test's docstring)
folder = Path(sys.argv[1])
store.use_program_store(folder)
scene = Scene(Bay.from_airfoil(naca("0012"), chord=1.0, rib_spacing=0.25, n_span=5, n_contour=16), Fabric())
parameters = Parameters(pressure=1e4, prestrain_span=0.02, prestrain_chord=0.02)
with_store = solve_equilibrium(scene, parameters, method="auto")
names = {path.name.split("-")[0] for path in folder.glob("*.bin")}
assert {"relax_jit", "static_state", "_jacobian_values"} <= names, names
store.use_program_store(None)
plain = solve_equilibrium(scene, parameters, method="auto")
assert with_store.converged and plain.converged
np.testing.assert_array_equal(np.asarray(with_store.nodes), np.asarray(plain.nodes))
print("same")
"""


def test_a_solve_is_the_same_with_the_store(tmp_path):
    """The solver's stored programs (relaxation, Newton, the static state) give the same equilibrium
    to the bit, and they are written to the store. In a process compiled as the command compiles
    (XLA's default code generation, not the test run's `support.command.TEST_XLA_FLAGS`: without LLVM's
    optimisations an exported program and the jitted one part by 1e-16 m), its small grid's
    relaxation too (a light program, `stored_jit`, would part them so)."""
    flags = " ".join(f for f in os.environ.get("XLA_FLAGS", "").split() if f not in TEST_XLA_FLAGS)
    done = subprocess.run([sys.executable, "-c", _SAME_SOLVE, str(tmp_path)], env=environment(XLA_FLAGS=flags),
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and done.stdout.strip() == "same", done.stderr[-3000:]
