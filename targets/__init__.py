"""Airfoil geometry targets: NACA sections, airfoil files and curve distance.

Public names (``__all__``): :class:`Airfoil`, a chord-normalised section in
Selig order with a smooth representation (thickness, camber, leading-edge
radius, resampling, signed distance; :class:`Projection`, the closest points
of :meth:`Airfoil.project`); :func:`naca`, NACA 4- and 5-digit sections
(Report 824 formulas; the analytic section :class:`NacaSection` of
:func:`parse_naca`); :func:`load_airfoil`, Selig or Lednicer ``.dat`` files
(it warns with :class:`AirfoilWarning` when it renormalises a slightly-off
chord); :func:`common_trailing_edge`, sections with open and closed trailing
edges brought to one form, for a bay or a wing.

The submodule ``targets.naca`` is shadowed by the function of the same name;
import its other names with ``from targets.naca import ...``.
"""

from .airfoil import Airfoil as Airfoil
from .contour import Projection as Projection
from .dat import AirfoilWarning as AirfoilWarning
from .dat import load_airfoil as load_airfoil
from .naca import NacaSection as NacaSection
from .naca import naca as naca
from .naca import parse_naca as parse_naca
from .trailing_edge import common_trailing_edge as common_trailing_edge

__all__ = ["Airfoil", "AirfoilWarning", "NacaSection", "Projection", "common_trailing_edge", "load_airfoil", "naca",
           "parse_naca"]
