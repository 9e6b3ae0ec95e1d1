"""Reports of the tests: a single bay's equilibrium as the report takes it (measured as a design is,
`evaluate_design`), and an earlier report's files in an output folder."""

from __future__ import annotations

import json
from pathlib import Path

from forward_solver import Wing
from inverse_design import evaluate_design
from inverse_design.app.output_folder import file_checksums


def measured(solution, target, scene, objective: str = "mid_bay"):
    """The `inverse_design.DesignResult` of one bay's equilibrium ``solution`` on ``scene`` against ``target``,
    measured as it is (not solved again): what `inverse_design.app.folder.write_report` writes."""
    return evaluate_design(scene, target, objective=objective, wing=Wing.from_scene(scene), solution=solution)


def earlier_report(folder, files: dict, checksums: bool = False, **extra) -> dict:
    """Write ``files`` (``{name: bytes}``) into ``folder`` and a ``summary.json`` of this package listing them
    (with their sizes and SHA-256, ``checksums``; and the keys ``extra``), as a report does; returns the summary."""
    folder = Path(folder)
    for name, data in files.items():
        (folder / name).write_bytes(data)
    summary = {"package": {"name": "inflatable-wing"}, "files": [*files, "summary.json"], **extra}
    if checksums:
        summary["checksums"] = file_checksums(folder, files)
    (folder / "summary.json").write_text(json.dumps(summary))
    return summary
