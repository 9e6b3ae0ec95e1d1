"""Forward solver: the pressurised fabric bay between two ribs (paper eq. 1-17).

Public names::

    Fabric, Bay, Scene, Solution, Result, ConvergenceError, PressureRamp,
    solve_equilibrium, simulate

Importing this package changes no JAX configuration: solvers run in float64
inside a thread-local ``jax.enable_x64`` scope (see `scene.float64_scope`).
"""

from .bay import Bay as Bay
from .explicit import DEFAULT_COURANT as DEFAULT_COURANT
from .explicit import PressureRamp as PressureRamp
from .explicit import simulate as simulate
from .fabric import Fabric as Fabric
from .scene import Scene as Scene
from .solution import ConvergenceError as ConvergenceError
from .solution import Result as Result
from .solution import Solution as Solution
from .solve import solve_equilibrium as solve_equilibrium

__all__ = [
    "Bay",
    "ConvergenceError",
    "DEFAULT_COURANT",
    "Fabric",
    "PressureRamp",
    "Result",
    "Scene",
    "Solution",
    "simulate",
    "solve_equilibrium",
]
