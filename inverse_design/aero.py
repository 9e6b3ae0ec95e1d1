"""Aerodynamic cost of a cured bay: NeuralFoil polars of its sections against the target's.

The geometric error of a design (`inverse_design.objectives`) says how far
the skin lies from the target; this module says what that costs in lift,
drag and pitching moment. Two sections of the equilibrium are compared with
the target profile over a range of angles of attack at one Reynolds number:

* the mid-bay section, ``solution.section(0.5)``: the largest bulge;
* the bay-average section: the mean of the sections over the span from rib to
  rib, i.e. the nodes of every span row averaged with trapezoid weights (half
  weight on the two rib rows). Rows are evenly spaced and `Solution.section`
  interpolates linearly between them, so this is exactly the mean of
  ``solution.section(eta)`` over ``eta`` in [0, 1]. It stands for the span
  mean profile that a strip-theory estimate of the whole bay would use.

The coefficients come from NeuralFoil (Sharpe, a neural network trained on
XFoil runs, in pure numpy; it ships its weights), an optional dependency:
``pip install "inflatable-wing[aero]"``. NeuralFoil fits an 8+8-weight Kulfan
(CST) shape to the coordinates by least squares, so its output depends on how
the contour is sampled (by about 5e-4 in CL between 65 and 257 points on NACA
2412); every section, the target included, is therefore resampled to the
same cosine distribution (`targets.Airfoil.resample`, `N_POINTS` points)
before the fit, and a section compared with itself gives exactly zero.

Conventions: angles in degrees from the x axis of the bay (the chord line of
the ribs); the section's coordinates are divided by ``chord`` and NeuralFoil
refers its coefficients to the section's own chord (leading edge to trailing
edge) and its Reynolds number to ``chord``; CM is the pitching moment about
the quarter chord, nose up positive. Differences are section minus target.
NeuralFoil's ``analysis_confidence`` (0 to 1) is reported per angle: low
values flag a query far from its training data or a flow it finds delicate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from numbers import Real

import numpy as np

from targets import Airfoil

__all__ = [
    "ALPHA_LIMIT",
    "AeroComparison",
    "AeroUnavailable",
    "MODEL_SIZES",
    "N_POINTS",
    "Polar",
    "PolarDifference",
    "aerodynamic_cost",
    "alpha_range",
    "bay_average_section",
    "compare_sections",
    "require_neuralfoil",
]

#: Largest |angle of attack| accepted, degrees. NeuralFoil's standalone model
#: covers attached and mildly separated flow; the statistics of its training
#: inputs that ship with it (mean cos(alpha) 0.9836, rms sin(2 alpha) 0.35)
#: match angles spread over about +-18 deg, so beyond 20 deg it extrapolates.
ALPHA_LIMIT = 20.0
#: Points of every section handed to NeuralFoil (cosine spaced, odd: the
#: leading edge is a node).
N_POINTS = 201
#: NeuralFoil's networks, smallest (fastest) to largest.
MODEL_SIZES = ("xxsmall", "xsmall", "small", "medium", "large", "xlarge", "xxlarge", "xxxlarge")
#: Most angles in one comparison (a polar at 0.01 deg over +-20 deg has 4001).
MAX_ALPHAS = 10_000

_INSTALL_HINT = 'pip install "inflatable-wing[aero]"'


class AeroUnavailable(ImportError):
    """NeuralFoil (the optional ``aero`` dependency) cannot be imported."""


def require_neuralfoil():
    """Import NeuralFoil and return the module.

    Raises:
        AeroUnavailable: when it (or its dependency AeroSandbox) is not
            installed; the message gives the install command.
    """
    try:
        import neuralfoil
    except ImportError as exc:
        raise AeroUnavailable(
            f"the aerodynamic comparison needs NeuralFoil, which is not installed ({exc}); "
            f"install it with: {_INSTALL_HINT}"
        ) from exc
    return neuralfoil


# ------------------------------------------------------------------ results
@dataclass(frozen=True)
class Polar:
    """NeuralFoil's coefficients of one section, one value per angle of attack.

    Attributes:
        cl: lift coefficient, shape ``(n_alpha,)``.
        cd: drag coefficient (profile drag), ``(n_alpha,)``.
        cm: pitching-moment coefficient about the quarter chord, ``(n_alpha,)``.
        confidence: NeuralFoil's ``analysis_confidence`` in [0, 1], ``(n_alpha,)``.
    """

    cl: np.ndarray
    cd: np.ndarray
    cm: np.ndarray
    confidence: np.ndarray

    def minus(self, reference: "Polar") -> "PolarDifference":
        """This polar minus ``reference`` (same angles)."""
        return PolarDifference(cl=self.cl - reference.cl, cd=self.cd - reference.cd, cm=self.cm - reference.cm)

    def as_dict(self) -> dict:
        return {"cl": self.cl, "cd": self.cd, "cm": self.cm, "confidence": self.confidence}


@dataclass(frozen=True)
class PolarDifference:
    """Section minus target coefficients, one value per angle of attack (``(n_alpha,)`` each)."""

    cl: np.ndarray
    cd: np.ndarray
    cm: np.ndarray

    def largest(self) -> dict:
        """``{"cl", "cd", "cm"}``: the largest absolute difference over the angles."""
        return {name: float(np.max(np.abs(getattr(self, name)))) for name in ("cl", "cd", "cm")}

    def as_dict(self) -> dict:
        return {"cl": self.cl, "cd": self.cd, "cm": self.cm}


@dataclass(frozen=True)
class AeroComparison:
    """Polars of the target, the mid-bay section and the bay-average section.

    Attributes:
        reynolds: Reynolds number, referred to the chord.
        alphas: angles of attack, degrees, ``(n_alpha,)``.
        target, mid_bay, bay_average: the `Polar` of each section.
        target_name: the target's name.
        model_size: the NeuralFoil network used.
        sections: the chord-normalised coordinates handed to NeuralFoil,
            ``{"target", "mid_bay", "bay_average"}: (N_POINTS, 2)`` in Selig order.
    """

    reynolds: float
    alphas: np.ndarray
    target: Polar
    mid_bay: Polar
    bay_average: Polar
    target_name: str = "target"
    model_size: str = "large"
    sections: dict = field(default_factory=dict, repr=False)

    @property
    def mid_bay_difference(self) -> PolarDifference:
        """Mid-bay minus target."""
        return self.mid_bay.minus(self.target)

    @property
    def bay_average_difference(self) -> PolarDifference:
        """Bay-average minus target."""
        return self.bay_average.minus(self.target)

    def as_dict(self) -> dict:
        """The JSON-ready record stored as ``summary["aero"]`` (numpy arrays as arrays)."""
        differences = {"mid_bay": self.mid_bay_difference, "bay_average": self.bay_average_difference}
        polars = {"target": self.target, "mid_bay": self.mid_bay, "bay_average": self.bay_average}
        return {
            "method": f"NeuralFoil {_neuralfoil_version()} ({self.model_size} network), "
                      f"sections resampled to {N_POINTS} cosine-spaced points",
            "target": self.target_name,
            "reynolds": float(self.reynolds),
            "alphas_deg": self.alphas,
            "sections": {name: polar.as_dict() for name, polar in polars.items()},
            "differences": {name: d.as_dict() for name, d in differences.items()},
            "max_abs_difference": {name: d.largest() for name, d in differences.items()},
            "min_confidence": {name: float(np.min(p.confidence)) for name, p in polars.items()},
            "note": "differences are section minus target over the angle range; CM about the "
                    "quarter chord; the bay-average section is the span mean of the skin's sections",
        }


def _neuralfoil_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("neuralfoil")
    except PackageNotFoundError:
        return "(version unknown)"


# ------------------------------------------------------------------ inputs
def _checked_reynolds(reynolds) -> float:
    if isinstance(reynolds, bool) or not isinstance(reynolds, Real):
        raise ValueError(f"reynolds must be a number (the chord Reynolds number), got {reynolds!r}")
    value = float(reynolds)
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"reynolds must be a positive finite number (the chord Reynolds number), "
                         f"got {reynolds!r}")
    return value


def _checked_alphas(alphas) -> np.ndarray:
    try:
        values = np.array(alphas, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"alphas must be an array of angles in degrees, got {alphas!r}") from None
    if values.ndim == 0:
        values = values[None]
    if values.ndim != 1 or values.size == 0:
        raise ValueError(f"alphas must be a non-empty 1-D array of angles in degrees, got shape {values.shape}")
    if values.size > MAX_ALPHAS:
        raise ValueError(f"alphas has {values.size} angles; at most {MAX_ALPHAS} are evaluated at once")
    if not np.isfinite(values).all():
        raise ValueError(f"alphas must be finite angles in degrees, got {values[~np.isfinite(values)][0]}")
    worst = float(np.max(np.abs(values)))
    if worst > ALPHA_LIMIT:
        raise ValueError(f"angles of attack must lie within +-{ALPHA_LIMIT:g} deg (NeuralFoil's attached-flow "
                         f"range), got {values[np.argmax(np.abs(values))]:g} deg; give angles in degrees")
    return values


def alpha_range(start: float, stop: float, step: float) -> np.ndarray:
    """Angles ``start, start + step, ...`` up to and including ``stop`` (degrees).

    Raises:
        ValueError: for a non-positive step, ``stop < start`` or angles
            outside +-`ALPHA_LIMIT`.
    """
    for name, value in (("start", start), ("stop", stop), ("step", step)):
        if not math.isfinite(value):
            raise ValueError(f"the angle range's {name} must be finite, got {value!r}")
    if not step > 0:
        raise ValueError(f"the angle step must be positive, got {step:g} deg")
    if stop < start:
        raise ValueError(f"the angle range must run upwards: stop {stop:g} deg is below start {start:g} deg")
    count = int(math.floor((stop - start) / step + 1e-9)) + 1
    if count > MAX_ALPHAS:
        raise ValueError(f"the angle range has {count} angles; at most {MAX_ALPHAS} (use a larger step)")
    return _checked_alphas(start + step * np.arange(count))


def _checked_model_size(model_size) -> str:
    if model_size not in MODEL_SIZES:
        raise ValueError(f"model_size must be one of {', '.join(MODEL_SIZES)}, got {model_size!r}")
    return model_size


# ------------------------------------------------------------------ sections
def bay_average_section(nodes) -> np.ndarray:
    """The span mean of the sections of a bay, ``(n_contour, 2)`` x-z in the nodes' unit.

    Trapezoid weights over the evenly spaced span rows (half on the rib
    rows): the mean of the piecewise-linear sections over the span.

    Args:
        nodes: ``(n_span, n_contour, 3)`` node positions.
    """
    nodes = np.asarray(nodes, dtype=np.float64)
    if nodes.ndim != 3 or nodes.shape[2] != 3 or nodes.shape[0] < 2:
        raise ValueError(f"nodes must have shape (n_span >= 2, n_contour, 3), got {nodes.shape}")
    weights = np.ones(nodes.shape[0])
    weights[[0, -1]] = 0.5
    weights /= weights.sum()
    mean = np.einsum("i,ijk->jk", weights, nodes)
    return mean[:, [0, 2]]


def _resampled(points, name: str, n_points: int) -> np.ndarray:
    """A closed section in chord units resampled to ``n_points`` cosine-spaced points, ``(n, 2)``.

    The section is scaled about the origin (the ribs' leading edge) so that
    its trailing edge lies at x = 1, as `targets.Airfoil` requires, resampled,
    and scaled back: the geometry handed on is the section's own.
    """
    points = np.asarray(points, dtype=np.float64)
    if not np.isfinite(points).all():
        raise ValueError(f"the {name} section has non-finite coordinates; solve the equilibrium again")
    if not np.array_equal(points[0], points[-1]):
        points = np.vstack([points, points[:1]])  # a periodic contour: back to the trailing edge
    x_te = float(points[0, 0])
    if not x_te > 0:
        raise ValueError(f"the {name} section's trailing edge is at x = {x_te:g} chord; expected an airfoil "
                         "section in Selig order from a closed bay (Bay.from_airfoil)")
    try:
        airfoil = Airfoil(points[:, 0] / x_te, points[:, 1] / x_te, name=name).resample(n_points)
    except ValueError as exc:
        raise ValueError(f"the {name} section is not a valid airfoil contour: {exc}") from None
    return np.stack([airfoil.x, airfoil.z], axis=-1) * x_te


def _polar(neuralfoil, coordinates: np.ndarray, alphas: np.ndarray, reynolds: float, model_size: str) -> Polar:
    aero = neuralfoil.get_aero_from_coordinates(coordinates, alpha=alphas, Re=reynolds, model_size=model_size)

    def column(key):
        return np.broadcast_to(np.asarray(aero[key], dtype=np.float64).reshape(-1), alphas.shape).copy()

    return Polar(cl=column("CL"), cd=column("CD"), cm=column("CM"), confidence=column("analysis_confidence"))


def compare_sections(target, mid_bay, bay_average, *, reynolds: float, alphas,
                     model_size: str = "large") -> AeroComparison:
    """NeuralFoil polars of two sections and the target, each resampled alike.

    Args:
        target: the target `targets.Airfoil` (chord-normalised).
        mid_bay, bay_average: sections in chord units, each a `targets.Airfoil`
            or the ``(n, 2)`` x-z nodes of a closed contour in Selig order
            (trailing edge, upper surface, leading edge, lower surface), as
            `forward_solver.Solution.section` gives them: the closing point
            (the first again) is added when missing. An array is scaled to
            put its trailing edge at x = 1 for resampling and scaled back.
        reynolds: chord Reynolds number, positive.
        alphas: angles of attack, degrees, 1-D, within +-`ALPHA_LIMIT`.
        model_size: NeuralFoil network, one of `MODEL_SIZES`.

    Returns:
        An `AeroComparison`.

    Raises:
        AeroUnavailable: NeuralFoil is not installed.
        ValueError: bad ``reynolds``, ``alphas`` or ``model_size``, or a
            section that is not an airfoil contour.
    """
    reynolds = _checked_reynolds(reynolds)
    alphas = _checked_alphas(alphas)
    model_size = _checked_model_size(model_size)
    neuralfoil = require_neuralfoil()

    def coordinates(section, name):
        if isinstance(section, Airfoil):  # chord-normalised already; an open trailing edge stays open
            resampled = section.resample(N_POINTS)
            return np.stack([resampled.x, resampled.z], axis=-1)
        return _resampled(section, name, N_POINTS)

    sections = {"target": coordinates(target, "target"), "mid_bay": coordinates(mid_bay, "mid-bay"),
                "bay_average": coordinates(bay_average, "bay-average")}
    polars = {name: _polar(neuralfoil, xz, alphas, reynolds, model_size) for name, xz in sections.items()}
    return AeroComparison(reynolds=reynolds, alphas=alphas, target_name=str(getattr(target, "name", "target")),
                          model_size=model_size, sections=sections, **polars)


def aerodynamic_cost(solution, target, chord: float, *, reynolds: float, alphas,
                     model_size: str = "large") -> AeroComparison:
    """Lift, drag and moment of the cured mid-bay and bay-average sections against the target.

    Args:
        solution: the equilibrium `forward_solver.Solution` of a closed
            airfoil bay (`forward_solver.Bay.from_airfoil`).
        target: the target `targets.Airfoil` (chord-normalised).
        chord: the ribs' chord, m (the sections are divided by it).
        reynolds: chord Reynolds number, positive (e.g. 1e6).
        alphas: angles of attack, degrees, 1-D, within +-`ALPHA_LIMIT`.
        model_size: NeuralFoil network, one of `MODEL_SIZES` (default "large").

    Returns:
        An `AeroComparison` (differences: section minus target).

    Raises:
        AeroUnavailable: NeuralFoil is not installed (the message gives the
            install command).
        ValueError: bad inputs, or sections that are not airfoil contours.
    """
    if isinstance(chord, bool) or not isinstance(chord, Real) or not (math.isfinite(chord) and chord > 0):
        raise ValueError(f"chord must be a positive length in metres, got {chord!r}")
    _checked_reynolds(reynolds)
    _checked_alphas(alphas)
    _checked_model_size(model_size)
    require_neuralfoil()  # before the geometry work: a missing package says so first
    mid = np.asarray(solution.section(0.5)) / chord
    average = bay_average_section(solution.nodes) / chord
    return compare_sections(target, mid, average, reynolds=reynolds, alphas=alphas, model_size=model_size)
