"""Small programs over a wing's stacked arrays, for the design's forward-mode transformation.

Under an eager JAX transformation (the design's ``jax.jvp`` of its wing
solve, `problem.DesignProblem`) every eager operation is compiled apiece, for
the primal and the tangents, and once per shape: each of these is one jitted
program instead (`benchmarks/design_programs.py` counts a design's
compilations: 46 / 56 / 93 for 1 / 3 / 40 bays with the eager operations, 34
/ 38 / 38 with these; 17 / 18 / 17 once each bay's nodes are sliced once,
`each_bay`, and its rows made in one program, `problem.DesignProblem`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["bay_nodes", "displacements", "each_bay", "joined", "prepend"]


@jax.jit
def prepend(f, g):
    """``[f, *g]``."""
    return jnp.concatenate([f[None], g])


@jax.jit
def joined(*parts):
    """``concatenate(parts)`` of flat float64 vectors."""
    return jnp.concatenate([jnp.asarray(part, jnp.float64).reshape(-1) for part in parts])


@jax.jit
def displacements(nodes, mounted):
    """The bays' displacements from their mounted shapes, flat."""
    return (nodes - mounted).reshape(-1)


@jax.jit
def _bay_nodes(nodes, k):
    return jax.lax.dynamic_index_in_dim(nodes, k, keepdims=False)


def bay_nodes(nodes, k: int):
    """Bay ``k``'s nodes of the wing's stacked ``nodes``: traced, by one program whose index is an
    argument, not a constant (a wing of 40 bays compiles it once, not 40 times); concrete, sliced."""
    return _bay_nodes(nodes, k) if isinstance(nodes, jax.core.Tracer) else nodes[k]


def each_bay(nodes, n_bays: int) -> list:
    """Per bay, its nodes: ``nodes`` itself if a list (one array per bay), else `bay_nodes` of the stacked
    array; under a transformation each slice is an operation of its own: slice once, pass the list."""
    return nodes if isinstance(nodes, list) else [bay_nodes(nodes, k) for k in range(n_bays)]
