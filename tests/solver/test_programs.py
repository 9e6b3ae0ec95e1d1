"""`forward_solver.programs`: a stored program is exported once per argument form and later loaded
without tracing, with the jitted function's results; with tracers, or with no folder, it is the
jitted function."""

import jax
import jax.numpy as jnp
import numpy as np

from forward_solver.programs import stored, use_program_store


def _counting():
    traced = []

    def scaled(x, offset, factor):
        traced.append(factor)
        return {"y": x * factor + offset, "sum": jnp.sum(x)}

    return scaled, traced


def test_a_stored_program_is_exported_once_then_loaded_without_tracing(tmp_path):
    scaled, traced = _counting()
    x = jnp.arange(4.0, dtype=jnp.float32)
    expected = jax.jit(scaled, static_argnames=("factor",))(x, 1.0, factor=2.0)
    previous = use_program_store(tmp_path)
    try:
        first = stored(scaled, static_argnames=("factor",))(x, 1.0, factor=2.0)
        assert len(list(tmp_path.glob("*.jax"))) == 1
        before = len(traced)
        again = stored(scaled, static_argnames=("factor",))  # (as a later process: nothing in memory)
        loaded = again(x, offset=1.0, factor=2.0)
        assert len(traced) == before  # loaded from the folder: the Python function was not traced
        for out in (first, loaded):
            np.testing.assert_array_equal(out["y"], expected["y"])
            np.testing.assert_array_equal(out["sum"], expected["sum"])
        again(jnp.arange(5.0, dtype=jnp.float32), 1.0, factor=2.0)  # another shape: another program
        again(x, 1.0, factor=3.0)  # another static value: another program
        assert len(list(tmp_path.glob("*.jax"))) == 3
        # Under a transformation the arguments are tracers: the jitted function, traced as usual.
        gradient = jax.grad(lambda v: again(v, 0.0, factor=3.0)["y"].sum())(x)
        np.testing.assert_array_equal(gradient, np.full(4, 3.0, np.float32))
    finally:
        use_program_store(previous)


def test_no_folder_no_files_and_a_damaged_file_is_exported_again(tmp_path):
    scaled, traced = _counting()
    x = jnp.ones(3, dtype=jnp.float32)
    stored(scaled, static_argnames=("factor",))(x, 0.0, factor=1.0)  # (no folder in use: the library's default)
    assert traced and not list(tmp_path.iterdir())
    previous = use_program_store(tmp_path)
    try:
        stored(scaled, static_argnames=("factor",))(x, 0.0, factor=1.0)
        (file,) = tmp_path.glob("*.jax")
        file.write_bytes(b"damaged")
        out = stored(scaled, static_argnames=("factor",))(x, 0.0, factor=1.0)
        np.testing.assert_array_equal(out["y"], np.ones(3, np.float32))
        assert file.read_bytes() != b"damaged"
    finally:
        use_program_store(previous)
