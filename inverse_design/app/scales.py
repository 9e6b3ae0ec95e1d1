"""Secondary-axis scales of the report's figures, in a module that imports nothing but the standard
library: a figure pickles its axes' functions by name, and the report's workers
(`inverse_design.app.workers`) unpickle it without importing JAX or the solver (a scale defined in
`inverse_design.app.bay_figures` made a worker import both, 0.7 s, before it could save the figure)."""

from __future__ import annotations

__all__ = ["Millimetres", "same"]


def same(values):
    """The identity (matplotlib's default secondary-axis function is a lambda, which does not pickle)."""
    return values


class Millimetres:
    """A secondary axis's scale: fractions of ``chord`` (m) to mm and back."""

    def __init__(self, chord: float):
        self.chord = chord

    def forward(self, d):
        return d * self.chord * 1e3

    def inverse(self, m):
        return m / (self.chord * 1e3)
