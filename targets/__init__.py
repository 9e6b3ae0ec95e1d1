"""Airfoil geometry targets: NACA sections, airfoil files and curve distance.

Public names:

* :class:`Airfoil`: a chord-normalised section in Selig order with a smooth
  representation (thickness, camber, leading-edge radius, resampling, signed
  distance).
* :func:`naca`: NACA 4- and 5-digit sections (Report 824 formulas).
* :func:`load_airfoil`: Selig or Lednicer ``.dat`` files; it warns with
  :class:`AirfoilWarning` when it renormalises a slightly-off chord.
* :func:`parse_naca`, :class:`NacaSection`: the analytic section behind
  :func:`naca` (mean line, thickness, surface).
* :class:`Projection`: closest points returned by :meth:`Airfoil.project`.
* :func:`common_trailing_edge`: sections with open and closed trailing edges
  brought to one form (closed by default), for a bay or a wing.

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
