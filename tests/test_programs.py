"""The program store (`forward_solver.programs`): a stored program loads in a fresh
process without being traced or lowered, gives what the jitted function gives, falls back to the
jitted function under transformations and without a store, and never keeps what it must not."""

import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from forward_solver import programs
from forward_solver.programs import stored, use_program_store

ROOT = Path(__file__).resolve().parents[1]


@stored(static_argnames=("power",))
def _scaled_powers(x, scale, power):
    return {"value": scale * x**power, "sum": jnp.sum(x)}


@pytest.fixture
def store(tmp_path):
    previous = use_program_store(tmp_path / "programs")
    _scaled_powers._programs.clear()
    try:
        yield programs.program_store()
    finally:
        use_program_store(None if previous is None else previous.path)
        _scaled_powers._programs.clear()


def _files(store):
    return sorted(store.path.glob("*.bin")) if store.path.exists() else []


def test_a_call_compiles_and_stores_once_per_static_value_shape_and_type(store, x64):
    x = jnp.arange(4.0)
    first = _scaled_powers(x, 2.0, 3)
    assert len(_files(store)) == 1
    again = _scaled_powers(x + 1.0, 0.5, 3)  # new values: the same program
    assert len(_files(store)) == 1
    _scaled_powers(x, 2.0, 2)  # another static value
    _scaled_powers(jnp.arange(5.0), 2.0, 3)  # another shape
    _scaled_powers(x.astype(jnp.float32), 2.0, 3)  # another type
    assert len(_files(store)) == 4
    reference = _scaled_powers.jitted(x + 1.0, 0.5, 3)
    np.testing.assert_array_equal(again["value"], reference["value"])
    np.testing.assert_array_equal(first["value"], 2.0 * np.arange(4.0) ** 3)


def test_traced_arguments_and_no_store_take_the_jitted_function(store, x64):
    x = jnp.linspace(0.5, 1.5, 3)
    grad = jax.grad(lambda s: jnp.sum(_scaled_powers(x, s, 2)["value"]))(2.0)
    np.testing.assert_allclose(grad, np.sum(np.asarray(x) ** 2), rtol=1e-14)
    batched = jax.vmap(lambda s: _scaled_powers(x, s, 2)["value"])(jnp.arange(3.0))
    np.testing.assert_allclose(batched, np.arange(3.0)[:, None] * np.asarray(x) ** 2, rtol=1e-14)
    assert _files(store) == []  # only traced calls so far
    use_program_store(None)
    _scaled_powers(x, 2.0, 2)
    assert _files(store) == []


def test_a_damaged_entry_is_compiled_again_and_replaced(store, x64):
    x = jnp.arange(3.0)
    _scaled_powers(x, 1.0, 2)
    (entry,) = _files(store)
    entry.write_bytes(b"not an executable")
    _scaled_powers._programs.clear()  # as a fresh process
    out = _scaled_powers(x, 3.0, 2)
    np.testing.assert_array_equal(out["value"], 3.0 * np.arange(3.0) ** 2)
    assert entry.read_bytes() != b"not an executable"


def test_an_executable_from_the_persistent_cache_is_used_but_not_stored(store, x64, monkeypatch):
    """A hit in JAX's persistent cache serialises without its object code (module docstring): the
    store must not keep it (here every compilation reports a hit, the salted one too)."""

    class Lowered:
        def __init__(self, lowered):
            self.lowered = lowered

        def compile(self):
            programs._listen("/jax/compilation_cache/cache_hits")  # as JAX reports a hit
            return self.lowered.compile()

    lower = _scaled_powers.lower_for_store
    monkeypatch.setattr(_scaled_powers, "lower_for_store", lambda *args: Lowered(lower(*args)))
    out = _scaled_powers(jnp.arange(3.0), 2.0, 1)
    np.testing.assert_array_equal(out["value"], 2.0 * np.arange(3.0))
    assert _files(store) == []


def test_a_plain_call_compiled_first_does_not_keep_the_store_from_storing(store, x64):
    """The plain jitted program in JAX's persistent cache (the test run's, conftest) is not the
    store's: lowered under a name that carries the store's key, the store compiles its own."""
    x = jnp.arange(6.0)
    _scaled_powers.jitted(x, 1.0, 4)  # the plain program, compiled (and cached) first
    _scaled_powers(x, 2.0, 4)
    assert len(_files(store)) == 1


_FRESH = r"""
import json, sys, jax
traces = []
jax.monitoring.register_event_duration_secs_listener(
    lambda event, duration, **kw: traces.append(kw.get("fun_name"))
    if event == "/jax/core/compile/jaxpr_trace_duration" else None)
from forward_solver.programs import use_program_store
use_program_store(sys.argv[1])
from forward_solver import Bay, Fabric, Parameters, Scene, forces as fk
from targets import naca
scene = Scene(Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=5, n_contour=16), Fabric())
with jax.enable_x64(True):
    geometry = scene.bay.geometry()
    params = scene.params(Parameters(pressure=1e4, prestrain_span=0.02, prestrain_chord=0.01,
                                     rib_thickness_scale=0.9))
    nodes = fk.mounted_compiled(geometry, params)
    reference = fk.mounted_compiled.jitted(geometry, params)
print(json.dumps({"difference": float(abs(nodes - reference).max()), "traces": traces}))
"""


def test_a_stored_program_loads_in_a_fresh_process_without_tracing(tmp_path):
    """Two fresh processes call `forces.mounted_compiled` with the store in ``tmp_path``: the first
    traces and compiles it (under its store name), the second loads it and traces only the jitted
    reference it compares with."""
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    runs = []
    for _ in range(2):
        done = subprocess.run([sys.executable, "-c", _FRESH, str(tmp_path / "programs")], cwd=ROOT, env=env,
                              capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        runs.append(json.loads(done.stdout.strip().splitlines()[-1]))
    assert all(run["difference"] == 0.0 for run in runs)
    def stored_traces(run):
        return [name for name in run["traces"] if name.startswith("mounted_nodes_program_")]

    assert len(stored_traces(runs[0])) == 1 and runs[0]["traces"].count("mounted_nodes") == 1
    assert stored_traces(runs[1]) == [] and runs[1]["traces"].count("mounted_nodes") == 1  # the reference
    assert len(list((tmp_path / "programs").glob("*.bin"))) == 1


def _join(threads) -> None:
    for thread in threads:
        thread.join(timeout=60)
        assert not thread.is_alive()


def _reads(store, monkeypatch) -> list:
    """Record ``(thread name, key)`` of every executable ``store`` reads from its folder."""
    import threading

    reads, read = [], store._read
    monkeypatch.setattr(store, "_read", lambda key: reads.append((threading.current_thread().name, key)) or read(key))
    return reads


def test_a_profiles_programs_are_loaded_ahead_by_the_next_run_and_taken_from_there(store, x64, monkeypatch):
    """`remember` lists what a run used; a later store (a fresh process) loads that list on its
    prefetch thread, and the calls take the executables from there instead of reading them again."""
    x = jnp.arange(4.0)
    _scaled_powers(x, 2.0, 3)
    _scaled_powers(jnp.arange(5.0), 2.0, 3)
    keys = list(store.used)
    assert len(keys) == 2 and len(_files(store)) == 2
    assert store.remember("default case") and not store.remember("default case")  # (unchanged: not rewritten)
    fresh = programs.ProgramStore(store.path)
    reads = _reads(fresh, monkeypatch)
    _join(fresh.prefetch("default case"))
    assert sorted(reads) == sorted(("program-store-prefetch", key) for key in keys)
    for key in keys:
        assert fresh.load(key) is not None
    assert len(reads) == 2 and fresh.used == keys  # taken from the prefetch, not read again
    assert fresh.prefetch("another profile") == []  # nothing remembered for it
    assert len(reads) == 2


def test_nothing_is_loaded_ahead_for_another_code_version_or_a_program_a_call_took_first(store, x64, monkeypatch):
    _scaled_powers(jnp.arange(4.0), 2.0, 3)
    _scaled_powers(jnp.arange(5.0), 2.0, 3)
    first, second = store.used
    store.remember("p")
    (recent,) = store.path.glob("recent-*.json")
    listed = json.loads(recent.read_text())
    recent.write_text(json.dumps(dict(listed, version="an older code version")))
    fresh = programs.ProgramStore(store.path)
    reads = _reads(fresh, monkeypatch)
    assert fresh.prefetch("p") == []
    assert reads == []
    recent.write_text(json.dumps(listed))
    fresh = programs.ProgramStore(store.path)
    reads = _reads(fresh, monkeypatch)
    assert fresh.load(first) is not None  # a call took it before the prefetch started
    _join(fresh.prefetch("p"))
    assert [key for _, key in reads] == [first, second] and reads[1][0] == "program-store-prefetch"
