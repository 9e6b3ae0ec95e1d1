"""What the solver's tests share: the default bay and its scene, a tight solve, the circle section, a row's
outward bulge, the item counts a module hands `threads.each`."""

import jax
import numpy as np

from forward_solver import Bay, Fabric, Scene, solve_equilibrium
from forward_solver import forces as fk
from forward_solver.reference.closed_forms import circle_contour
from targets import Airfoil, naca


def default_bay(n_span: int = 9, n_contour: int = 32, **options) -> Bay:
    """The default bay on an ``n_span x n_contour`` grid: NACA 2412 ribs, chord 1 m, ribs 0.25 m apart
    (``options``: `Bay.from_airfoil`'s others)."""
    return Bay.from_airfoil(naca("2412"), chord=1.0, rib_spacing=0.25, n_span=n_span, n_contour=n_contour,
                            **options)


def default_scene(n_span: int = 9, n_contour: int = 32, fabric: Fabric | None = None) -> Scene:
    """The default bay (`default_bay`) in the default fabric (2e5 N/m, Poisson 0.25), or ``fabric``."""
    return Scene(default_bay(n_span, n_contour), Fabric() if fabric is None else fabric)


#: The residual of the derivative tests' solves: their central differences resolve 1e-5 relative.
TIGHT_RTOL = 1e-12


def tight_solve(scene: Scene, parameters, initial=None):
    """``solve_equilibrium`` at `TIGHT_RTOL` by relax+newton (whose LU factor the implicit derivative reuses)."""
    return solve_equilibrium(scene, parameters, rtol=TIGHT_RTOL, method="relax+newton", initial=initial)


def circle(n_points: int = 257) -> Airfoil:
    """A circle of diameter 1 in Selig order: from (1, 0) over the top and back."""
    return Airfoil(*circle_contour(n_points), name="circle")


def outward_displacement(bay: Bay, sol, row: int) -> np.ndarray:
    """Displacement of a grid row along the mounted surface's outward unit normal, m."""
    with jax.enable_x64(True):
        x0 = bay.nominal_nodes()
        area = np.asarray(fk.node_area_vectors(x0, bay.periodic))
    normal = area / np.linalg.norm(area, axis=-1, keepdims=True)
    return np.sum((sol.nodes[row] - np.asarray(x0)[row]) * normal[row], axis=-1)


def counted_each(monkeypatch, module) -> list:
    """The item counts of each call of ``module.each`` (`forward_solver.solvers.threads.each`) from now on
    (the calls still run as they would)."""
    counts, each = [], module.each

    def counted(function, count):
        counts.append(count)
        return each(function, count)

    monkeypatch.setattr(module, "each", counted)
    return counts
