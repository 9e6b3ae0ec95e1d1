"""The iterate history of a design: one entry per forward solve, the best iterate, the per-iterate hook."""

from __future__ import annotations

import math

import numpy as np

from .variables import DesignVariables, key_of

__all__ = ["History"]


class History:
    """The iterates of one design, as `DesignResult.history` holds them.

    Args:
        variables: the design's `DesignVariables` (an entry records the optimised values).

    Attributes:
        entries: one dict per iterate (`record`).
        on_record: called with each new entry (the progress bar, the user's callback), or None.
    """

    def __init__(self, variables: DesignVariables):
        self.variables = variables
        self.entries: list[dict] = []
        self.on_record = None
        self._at: dict = {}  # the newest entry at each point, by `variables.key_of`

    def record(self, u, objective, gradient_norm=math.nan, *, solution, constraints=None,
               jacobian: str | None = None) -> dict:
        """Append the entry of an iterate at the scaled vector ``u`` (``solution``: its `BaysSolution`;
        ``jacobian``: its Jacobian's blocks, as the progress bar shows them) and call `on_record` with it."""
        entry = {
            "values": self.variables.values(np.asarray(u, dtype=np.float64)),
            "objective": float(objective),
            "gradient_norm": float(gradient_norm),
            "steps": int(np.max(solution.steps)),
        }
        if constraints is not None:
            entry["constraints"] = [float(c) for c in constraints]
        if jacobian is not None:
            entry["jacobian"] = jacobian
        self.entries.append(entry)
        self._at[key_of(u)] = entry
        if self.on_record is not None:
            self.on_record(entry)
        return entry

    def at(self, u) -> dict | None:
        """The newest entry recorded at the scaled vector ``u`` (the same floats), or None."""
        return self._at.get(key_of(u))

    def best(self) -> np.ndarray | None:
        """Scaled vector of the best recorded iterate (None before any): the feasible one (every
        smooth constraint >= 0) with the least objective in size, else the least violating one."""

        def violation(entry):
            return max([0.0] + [-c for c in entry.get("constraints", [])])

        if not self.entries:
            return None
        best = min(self.entries, key=lambda h: (violation(h), abs(h["objective"])))
        return self.variables.from_values(best["values"])
