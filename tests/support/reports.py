"""A single bay's equilibrium as the report takes it: measured as a design is (`evaluate_design`)."""

from __future__ import annotations

from forward_solver import Wing
from inverse_design import evaluate_design


def measured(solution, target, scene, objective: str = "mid_bay"):
    """The `inverse_design.DesignResult` of one bay's equilibrium ``solution`` on ``scene`` against ``target``,
    measured as it is (not solved again): what `inverse_design.app.folder.write_report` writes."""
    return evaluate_design(scene, target, objective=objective, wing=Wing.from_scene(scene), solution=solution)
