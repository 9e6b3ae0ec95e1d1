"""Forward solver: the pressurised fabric bay between two ribs (paper eq. 1-17).

Public names::

    Fabric, Bay, Scene, Parameters, Solution, Result, ConvergenceError,
    PressureRamp, solve_equilibrium, simulate, Wing, solve_wing, solve_bays,
    rib_section

``Parameters.rib_shape`` offsets the rib contours (`rib_shape`: Bernstein
coefficients of a class-shape offset); `rib_section` is the designed rib as
an airfoil.

``solve_equilibrium`` is differentiable in its `Parameters` (``jax.grad``,
``jax.jacfwd``; implicit adjoint by default, see `adjoint`).

Importing this package changes no JAX configuration: solvers run in float64
inside a thread-local ``jax.enable_x64`` scope (see `scene.float64_scope`).
The explicit solvers iterate in float32 on request (``precision="float32"``),
only for tolerances float32 can meet (the rule is in `_precision`).

Analytic references for validation: `closed_forms`; an independent numpy
residual: `independent_residual`.
"""

from .model.bay import Bay as Bay
from .solvers.explicit import DEFAULT_COURANT as DEFAULT_COURANT
from .solvers.explicit import PressureRamp as PressureRamp
from .solvers.explicit import simulate as simulate
from .model.fabric import Fabric as Fabric
from .model.parameters import Parameters as Parameters
from .model.rib_shape import rib_section as rib_section
from .model.scene import Scene as Scene
from .model.wing import Wing as Wing
from .solution import BaysSolution as BaysSolution
from .solution import ConvergenceError as ConvergenceError
from .solution import Result as Result
from .solution import Solution as Solution
from .solve import solve_equilibrium as solve_equilibrium
from .solvers.bays import solve_bays as solve_bays
from .solvers.bays import solve_wing as solve_wing

__all__ = [
    "Bay",
    "BaysSolution",
    "ConvergenceError",
    "DEFAULT_COURANT",
    "Fabric",
    "Parameters",
    "PressureRamp",
    "Result",
    "rib_section",
    "Scene",
    "Solution",
    "simulate",
    "solve_equilibrium",
    "solve_bays",
    "solve_wing",
    "Wing",
]
