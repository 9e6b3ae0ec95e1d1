"""Synthetic biaxial tests: readings of a known law along load-ratio paths, and the shipped example.

`synthetic_test` loads a law along the standard paths (`STANDARD_PATHS`:
1:1, 2:1, 1:2, 1:0, 0:1, warp:weft, as MSAJ/M-02-1995 and EN 17117-1 load a
cruciform specimen) in equal steps of the larger arm's tension, and records
the strains where the law carries each load (its inverse, by Newton's
method), with optional noise on the tensions. The checks use it (a law
recovered from its own readings), and it made the example test shipped
with the command (`example_readings` of `example_surface`, written by
`write_test` as ``inverse_design/cases/fabric_test_example.csv``): labelled
synthetic.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .readings import BiaxialTest, path_label, readings_from_arrays
from .surface import EnergySurface, monomials

__all__ = ["EXAMPLE_HEADER", "EXAMPLE_LAW", "EXAMPLE_LOAD", "STANDARD_PATHS", "example_readings", "example_surface", "linear_law",
           "synthetic_test", "write_test"]

#: The load-ratio paths of a standard biaxial test, warp:weft.
STANDARD_PATHS = ((1, 1), (2, 1), (1, 2), (1, 0), (0, 1))


def linear_law(stiffness_warp: float, stiffness_weft: float, poisson: float):
    """Eq. (10) of the paper without its viscous term, as a law ``(e_warp, e_weft) -> (T_warp, T_weft)``, N/m:
    ``T_warp = (E_warp e_warp + nu E_weft e_weft) / (1 - nu^2)`` and likewise ``T_weft``."""
    scale = 1.0 / (1.0 - poisson * poisson)

    def tensions(e_warp, e_weft):
        return ((stiffness_warp * e_warp + poisson * stiffness_weft * e_weft) * scale,
                (stiffness_weft * e_weft + poisson * stiffness_warp * e_warp) * scale)

    return tensions


def _inverse(law, target, start, tol: float = 1e-13, max_steps: int = 60) -> np.ndarray:
    """The strains where ``law`` carries ``target`` tensions: Newton's method, the tangent by central
    differences (any law, reciprocal or not)."""
    e = np.array(start, np.float64)
    scale = max(float(np.max(np.abs(target))), 1.0)
    h = 1e-7
    for _ in range(max_steps):
        residual = np.array(law(e[0], e[1]), np.float64) - target
        if np.max(np.abs(residual)) <= tol * scale:
            return e
        jacobian = np.column_stack([(np.array(law(e[0] + h, e[1])) - np.array(law(e[0] - h, e[1]))) / (2 * h),
                                    (np.array(law(e[0], e[1] + h)) - np.array(law(e[0], e[1] - h))) / (2 * h)])
        e = e - np.linalg.solve(jacobian, residual)
    raise ValueError(f"the law carries no strain with the tensions {target.tolist()} N/m (Newton did not converge)")


def synthetic_test(law, max_tension: float, steps: int = 10, paths=STANDARD_PATHS, noise: float = 0.0,
                   seed: int = 0, source: str = "synthetic") -> BiaxialTest:
    """Readings of ``law`` along load-ratio ``paths`` (module docstring).

    Args:
        law: ``(e_warp, e_weft) -> (T_warp, T_weft)``, N/m (an `surface.EnergySurface`'s ``tensions``,
            `linear_law`, ...).
        max_tension: the larger arm's tension at a path's last reading, N/m.
        steps: readings per path, at ``max_tension / steps`` apart (zero load is not a reading).
        paths: ``(warp, weft)`` load ratios.
        noise: relative standard deviation of the recorded tensions (0.01: 1% of each reading).
        seed: the noise's seed.
        source: what the readings are called.

    Returns:
        A checked `readings.BiaxialTest`, its paths labelled.
    """
    rng = np.random.default_rng(seed)
    columns, labels = [], []
    for ratio in paths:
        ratio = np.asarray(ratio, np.float64) / max(ratio)
        e = np.zeros(2)
        for k in range(1, steps + 1):
            target = ratio * max_tension * k / steps
            e = _inverse(law, target, e)
            recorded = target * (1.0 + noise * rng.standard_normal(2))
            columns.append([e[0], e[1], *recorded])
            labels.append(path_label(*ratio))
    array = np.array(columns)
    return readings_from_arrays(*array.T, paths=labels, source=source)


def write_test(path, test: BiaxialTest, header: str = "") -> Path:
    """Write ``test`` as a test file (`readings.read_test`'s format, with ``load_ratio``); ``header``: comment
    lines put first (each prefixed with ``#``)."""
    lines = [f"# {line}".rstrip() for line in header.splitlines()]
    lines.append("strain_warp,strain_weft,tension_warp,tension_weft,load_ratio")
    for k in range(test.size):
        lines.append(f"{test.strain_warp[k]:.6f},{test.strain_weft[k]:.6f},{test.tension_warp[k]:.1f},"
                     f"{test.tension_weft[k]:.1f},{test.paths[k]}")
    path = Path(path)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


# ------------------------------------------------------------------ the example
#: The example law's tensions, N/m (docs/fabric_test.md, "The example"): the tangent at zero strain
#: (``a`` warp, ``b`` weft, ``c`` coupling), the stiffening with the strain (``s`` its own strain
#: squared, ``t`` cubed) and the warp's stiffening with the weft's load (``g``)::
#:
#:     T_warp = a e_w + c e_f + s_w e_w^2 + t_w e_w^3 + g e_w e_f
#:     T_weft = b e_f + c e_w + s_f e_f^2 + t_f e_f^3 + g e_w^2 / 2
EXAMPLE_LAW = {"a": 1.4e5, "b": 0.9e5, "c": 0.35e5, "s_w": 1.0e6, "s_f": 1.5e6, "t_w": 3.0e7, "t_f": 4.0e7, "g": 1.0e6}
#: The example test: the larger arm's load at the end of each path, N/m, readings per path, and the
#: tensions' noise (relative) with its seed.
EXAMPLE_LOAD = {"max_tension": 8000.0, "steps": 10, "noise": 0.005, "seed": 2024}


def example_surface(law: dict = EXAMPLE_LAW, strain_range=((-0.1, 0.1), (-0.1, 0.1))) -> EnergySurface:
    """The example law (`EXAMPLE_LAW`) as a degree-4 strain-energy surface (over ``strain_range``, warp and
    weft: where its polynomial holds)."""
    energy = {(2, 0): law["a"] / 2, (1, 1): law["c"], (0, 2): law["b"] / 2, (3, 0): law["s_w"] / 3,
              (2, 1): law["g"] / 2, (0, 3): law["s_f"] / 3, (4, 0): law["t_w"] / 4, (0, 4): law["t_f"] / 4}
    return EnergySurface(4, tuple(float(energy.get(term, 0.0)) for term in monomials(4)), *strain_range)


def example_readings() -> BiaxialTest:
    """The example test's readings (the shipped file holds them, rounded as `write_test` writes them)."""
    return synthetic_test(example_surface().polynomial_tensions, source="fabric_test_example.csv", **EXAMPLE_LOAD)


#: The comment lines at the head of the example file.
EXAMPLE_HEADER = """SYNTHETIC biaxial test: not a measured fabric. Readings of a known law (docs/fabric_test.md,
"The example"), made by forward_solver.model.biaxial.synthetic.example_readings: a woven fabric that is soft at low
strain and stiffens (crimp interchange), warp stiffer than weft, its warp stiffer when the weft is stretched:
T_warp = 1.4e5 e_w + 0.35e5 e_f + 1.0e6 e_w^2 + 3.0e7 e_w^3 + 1.0e6 e_w e_f
T_weft = 0.9e5 e_f + 0.35e5 e_w + 1.5e6 e_f^2 + 4.0e7 e_f^3 + 0.5e6 e_w^2       (N/m, strains as fractions)
Five load-ratio paths warp:weft (1:1, 2:1, 1:2, 1:0, 0:1) to 8 kN/m on the larger arm in ten steps,
tensions recorded with 0.5% noise (seed 2024)."""
