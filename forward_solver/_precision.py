"""How the package gets float64 from JAX without changing the caller's configuration."""

from __future__ import annotations

from contextlib import contextmanager

import jax

__all__ = ["float64_scope"]


def _any_tracer(*values) -> bool:
    leaves = jax.tree_util.tree_leaves(values)
    return any(isinstance(v, jax.core.Tracer) for v in leaves)


@contextmanager
def float64_scope(*traced_inputs):
    """Run the enclosed JAX work with float64 available, without touching global config.

    The package never flips ``jax_enable_x64`` globally (importing it changes
    nothing for other JAX code). A concrete call enters the thread-local
    ``jax.enable_x64(True)`` context for its own duration. Under a caller's
    JAX transformation (``jax.grad``, ``jax.jit``) the caller's setting wins,
    and float64 must already be on.

    Raises:
        RuntimeError: when traced by a caller whose JAX runs in float32 mode.
    """
    if _any_tracer(*traced_inputs):
        if not jax.config.jax_enable_x64:
            raise RuntimeError(
                "forward_solver computes in float64 but is being transformed by JAX in float32 "
                "mode: call jax.config.update('jax_enable_x64', True) first, or wrap the "
                "transformation in `with jax.enable_x64(True):`"
            )
        yield
        return
    with jax.enable_x64(True):
        yield
