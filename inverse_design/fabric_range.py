"""The fibre strains a design reaches against the strains its fabric's test covered.

A fibre law fitted to a biaxial test (`model.biaxial.fit_law`) is trusted over the
strains the test covered; beyond them it is continued along its tangent
(`model.biaxial.surface`). `strain_range` gives the least and largest cell strain
of every bay of an equilibrium, per wing direction; `outside_tested_range`
the one line that says where they leave the tested range, which a design,
a single equilibrium and the Monte Carlo samples of a tolerance analysis
warn with (``warnings.warn``: the command shows it and keeps it in the
summary's warnings).
"""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np

from forward_solver.programs import cell_strains

__all__ = ["FabricRangeWarning", "bay_strains", "outside_tested_range", "strain_range", "warn_outside_tested_range"]


class FabricRangeWarning(UserWarning):
    """Fibre strains beyond those the fabric's biaxial test covered (`outside_tested_range`)."""


def bay_strains(scene, parameters, nodes) -> tuple:
    """``(span, chord)``: the ``(least, largest)`` cell strain of one bay's equilibrium ``nodes`` under
    ``parameters`` (a `forward_solver.Parameters`), per wing direction."""
    with jax.enable_x64(True):
        span, chord = cell_strains(jnp.asarray(nodes, jnp.float64), scene.bay.geometry(), scene.params(parameters),
                                   scene.physics(dynamic=False))
    span, chord = np.asarray(span), np.asarray(chord)
    return (float(span.min()), float(span.max())), (float(chord.min()), float(chord.max()))


def strain_range(result) -> dict:
    """``{"span": [least, largest], "chord": [...]}``: the cell strains of every bay of ``result`` (a
    `DesignResult`) at its equilibrium."""
    sol = result.wing_solution
    found = [bay_strains(scene, sol.bay_solution(k).parameters, sol.nodes[k])
             for k, scene in enumerate(result.per_bay.scenes)]
    return {"span": [min(f[0][0] for f in found), max(f[0][1] for f in found)],
            "chord": [min(f[1][0] for f in found), max(f[1][1] for f in found)]}


def _percent(value: float) -> str:
    return f"{100.0 * value:.3g}%"


def outside_tested_range(fabric, reached: dict, what: str = "the design") -> str | None:
    """One line naming each wing direction whose strains in ``reached`` (`strain_range`'s form) leave the
    range ``fabric``'s law was tested over, with the strain reached and the range; None when they stay in
    it or the fabric's law is eq. (10) (no test)."""
    tested = fabric.strain_range
    if tested is None:
        return None
    names = {"span": "warp" if fabric.warp == "span" else "weft", "chord": "weft" if fabric.warp == "span" else "warp"}
    parts = []
    for direction in ("span", "chord"):
        (low, high), (least, largest) = tested[direction], reached[direction]
        beyond = [v for v, out in ((least, least < low), (largest, largest > high)) if out]
        if beyond:
            parts.append(f"{direction} fibres ({names[direction]}) {' and '.join(_percent(v) for v in beyond)}, tested "
                         f"{_percent(low)} to {_percent(high)}")
    if not parts:
        return None
    return (f"the fibre strains of {what} leave the range {fabric.law.source} tested: {'; '.join(parts)}; the law is "
            "continued along its tangent there (docs/fabric_test.md): test the fabric over those strains, or read "
            "those cells' tensions as extrapolated")


def warn_outside_tested_range(result, what: str = "the design") -> None:
    """``warnings.warn`` `outside_tested_range`'s line for ``result`` (a `DesignResult`), if any."""
    fabric = result.per_bay.scenes[0].fabric
    if fabric.law is None:
        return
    line = outside_tested_range(fabric, strain_range(result), what)
    if line is not None:
        warnings.warn(line, FabricRangeWarning, stacklevel=3)
