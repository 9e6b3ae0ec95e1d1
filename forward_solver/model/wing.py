"""`Wing`: ribs along the span, each with its section, chord and span station (a tapered wing).

The bays between consecutive ribs are `Bay`s on one grid shape (`Wing.bays`),
or `Scene`s of one fabric (`Wing.scenes`); one bay is the wing of its two
ribs (`Wing.from_scene`). Their equilibrium: `forward_solver.solve_wing`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from targets import common_trailing_edge

from .bay import N_CONTOUR, N_SPAN, Bay
from .fabric import Fabric
from .scene import Scene

__all__ = ["Wing"]


@dataclass(frozen=True)
class Wing:
    """Ribs along the span: sections, chords and span stations.

    Args:
        airfoils: the rib sections (`targets.Airfoil`), root to tip, N + 1 >= 2.
        chords: the rib chords, m, one per rib.
        stations: the ribs' span positions y, m, strictly increasing.
        trailing_edge: how ribs with open and closed trailing edges are brought
            to one form (every bay runs one seam form): "close", "open" or
            "as-given" (`targets.common_trailing_edge`).
        fix_trailing_edge: hold every bay's trailing-edge line (a seam; see
            `Bay.from_airfoil`).

    Attributes:
        sections: the rib sections the bays are built on: ``airfoils`` with
            their trailing edges brought to one form.
        trailing_edge_changes: a note per changed rib (``index`` = the rib,
            ``label``, ``gap_before``, ``gap_after`` in chord units, ``blend``).

    Raises:
        ValueError: for fewer than two ribs, lists of different lengths,
            stations that do not increase or a non-positive chord, or ribs of
            both trailing-edge forms with ``trailing_edge="as-given"``.
    """

    airfoils: tuple
    chords: tuple
    stations: tuple
    trailing_edge: str = "close"
    fix_trailing_edge: bool = True

    def __post_init__(self):
        n = len(self.airfoils)
        if n < 2:
            raise ValueError(f"a wing needs at least two ribs, got {n}")
        if not (len(self.chords) == len(self.stations) == n):
            raise ValueError(f"give one chord and one station per rib: {n} airfoils, "
                             f"{len(self.chords)} chords, {len(self.stations)} stations")
        if not all(np.isfinite(c) and c > 0 for c in self.chords):
            raise ValueError(f"rib chords must be positive lengths in m, got {self.chords}")
        if not (np.all(np.isfinite(self.stations)) and np.all(np.diff(self.stations) > 0)):
            raise ValueError(f"rib stations must increase strictly from root to tip (m), got {self.stations}")
        labels = [f"rib {k} ({getattr(a, 'name', 'airfoil')})" for k, a in enumerate(self.airfoils)]
        sections, changes = common_trailing_edge(self.airfoils, self.trailing_edge, labels)
        object.__setattr__(self, "sections", tuple(sections))
        object.__setattr__(self, "trailing_edge_changes", tuple(changes))

    @property
    def n_bays(self) -> int:
        return len(self.airfoils) - 1

    def bays(self, n_span: int = N_SPAN, n_contour: int = N_CONTOUR) -> list[Bay]:
        """The bays, root to tip, each between ribs k and k + 1, all on one grid shape.

        Made once per grid shape (bays are immutable): the command, the design and its report
        ask for them several times (40 bays: 0.35 s each time).
        """
        made = self.__dict__.setdefault("_bays", {})  # a cache, not a field (frozen dataclass)
        key = (int(n_span), int(n_contour))
        if key not in made:
            made[key] = tuple(Bay.from_airfoil(self.sections[k], chord=self.chords[k],
                                               rib_spacing=self.stations[k + 1] - self.stations[k], n_span=n_span,
                                               n_contour=n_contour, fix_trailing_edge=self.fix_trailing_edge,
                                               tip_airfoil=self.sections[k + 1], tip_chord=self.chords[k + 1])
                              for k in range(self.n_bays))
        return list(made[key])

    def scenes(self, fabric: Fabric, n_span: int = N_SPAN, n_contour: int = N_CONTOUR, **switches) -> list[Scene]:
        """The bays as `Scene`s of one fabric and one set of physics switches (`Scene`'s keywords)."""
        return [Scene(bay, fabric, **switches) for bay in self.bays(n_span, n_contour)]

    @classmethod
    def from_scene(cls, scene: Scene) -> "Wing":
        """The one-bay wing of ``scene``'s bay (built with `Bay.from_airfoil`): its two ribs'
        sections and chords at stations ``(0, rib_spacing)``; ``bays`` on the bay's grid rebuilds it.

        Raises:
            ValueError: for a bay not built from an airfoil (a flat panel).
        """
        bay = scene.bay if isinstance(scene, Scene) else scene
        if getattr(bay, "airfoil", None) is None:
            raise ValueError("Wing.from_scene needs a bay built with Bay.from_airfoil (it keeps the rib "
                             "sections); solve a flat panel with solve_bays([scene]) or solve_equilibrium")
        tip = bay.airfoil if bay.tip_airfoil is None else bay.tip_airfoil
        return cls(airfoils=(bay.airfoil, tip), chords=(bay.chord_root, bay.chord_tip),
                   stations=(0.0, bay.rib_spacing), fix_trailing_edge=bay.fix_trailing_edge)
