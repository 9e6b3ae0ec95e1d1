"""Forward solver: the pressurised fabric bay between two ribs (paper eq. 1-17).

The public names are ``__all__``'s. The choices are values, their shortcut
strings naming the defaults::

    Relax, Newton, RelaxNewton, Explicit, Auto        # solve_equilibrium(method=...)
    ImplicitAdjoint, UnrolledAdjoint                  # solve_equilibrium(adjoint=...)
    SparseLU, BiCGStab                                # ImplicitAdjoint(linear_solver=...)
    Loop, Batch                                       # solve_bays(strategy=...)

``solve_equilibrium`` is differentiable in its `Parameters` (``jax.grad``,
``jax.jacfwd``; `derivatives`); ``Parameters.rib_shape`` offsets the rib
contours (`model.rib_shape`) and `rib_section` is the designed rib as an
airfoil. The layers are folders (docs/architecture.md): `model`, `forces`
(the kernel), `solvers`, `derivatives`, `reference` (independent checks)
and `compilation` (which the physics never imports). A fabric's biaxial test
is read and fitted by ``read_test`` and ``fit_law`` (`model.biaxial`, NumPy
only; docs/fabric_test.md), and the fit is ``Fabric(law=...)``. Importing this package
changes no JAX configuration: solvers run in float64 inside a thread-local
``jax.enable_x64`` scope (`precision`).
"""

from .derivatives.implicit import ImplicitAdjoint as ImplicitAdjoint
from .derivatives.implicit import SparseLU as SparseLU
from .derivatives.krylov import BiCGStab as BiCGStab
from .derivatives.unrolled import UnrolledAdjoint as UnrolledAdjoint
from .model.bay import Bay as Bay
from .model.biaxial import FittedLaw as FittedLaw
from .model.biaxial import TestFileError as TestFileError
from .model.biaxial import fit_law as fit_law
from .model.biaxial import read_test as read_test
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
from .solvers.bays import Batch as Batch
from .solvers.bays import Loop as Loop
from .solvers.bays import solve_bays as solve_bays
from .solvers.bays import solve_wing as solve_wing
from .solvers.chain import Auto as Auto
from .solvers.explicit import DEFAULT_COURANT as DEFAULT_COURANT
from .solvers.explicit import PressureRamp as PressureRamp
from .solvers.explicit import simulate as simulate
from .solvers.methods import Explicit as Explicit
from .solvers.methods import Newton as Newton
from .solvers.methods import Relax as Relax
from .solvers.methods import RelaxNewton as RelaxNewton

__all__ = ["Auto", "Batch", "Bay", "BaysSolution", "BiCGStab", "ConvergenceError", "DEFAULT_COURANT", "Explicit",
           "Fabric", "FittedLaw", "ImplicitAdjoint", "Loop", "Newton", "Parameters", "PressureRamp", "Relax", "RelaxNewton",
           "Result", "read_test", "rib_section", "Scene", "Solution", "SparseLU", "simulate", "fit_law", "solve_equilibrium", "solve_bays",
           "solve_wing", "TestFileError", "UnrolledAdjoint", "Wing"]
