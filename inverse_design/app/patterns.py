"""A bay's cut-ready files written from its design: its flat panels and its ribs' templates.

The panels are laid flat from the design's cut lengths (`inverse_design.flat_panels.bay_panels`)
and the ribs drawn from their designed sections (`flat_panels.rib_template`) here, in the
command's process; the files are drawn by `cut_files` (DXF, SVG), directly or by the report's
workers (``writer``).
"""

from __future__ import annotations

from pathlib import Path

from ..flat_panels import bay_panels, rib_template
from .cut_files import MM, write_panel_files, write_rib_dxf

__all__ = ["write_bay_patterns"]


def write_bay_patterns(folder, scene, parameters, bay: int = 0, ribs=(0, 1),
                       seam_allowance_m: float = 0.01, rib_templates: bool = True, writer=None,
                       panels=None) -> list[str]:
    """Write one bay's panels (DXF and SVG) and its two ribs' templates into ``folder``.

    Args:
        folder: the (staging) folder.
        scene: the bay's `forward_solver.Scene`.
        parameters: the bay's design `Parameters`.
        bay: the bay's index (file names and labels).
        ribs: the indices of its root and tip ribs.
        seam_allowance_m: the seam allowance, metres (>= 0).
        rib_templates: False leaves the ribs out (a wing writes each shared rib once).
        writer: ``writer(path, function, *args)`` writes each file (a panel's DXF and its SVG
            beside it, a rib's DXF), as ``function(path, *args)`` does (the default); the report's
            may hand it to its `workers.ReportWorkers` instead.
        panels: the bay's panels already laid out (the marker's), or None: laid out here.

    Returns:
        ``(names, panels)``: the names of the files written and the `flat_layout.Panel` objects.
    """
    folder = Path(folder)
    allowance = seam_allowance_m * MM
    if writer is None:
        def writer(path, function, *args):
            function(path, *args)
    names = []
    panels = bay_panels(scene, parameters, bay=bay) if panels is None else panels
    for panel in panels:  # (its DXF and SVG from one drawing: `cut_files.write_panel_files`)
        name = f"pattern_bay_{bay}_{panel.name}"
        writer(folder / f"{name}.dxf", write_panel_files, panel, allowance)
        names += [f"{name}.dxf", f"{name}.svg"]
    if rib_templates and scene.bay.periodic and scene.bay.airfoil is not None:
        for row, rib in zip((0, -1), ribs):
            if rib is None:
                continue
            name = f"rib_{rib}.dxf"
            chord = (scene.bay.chord_root if row == 0 else scene.bay.chord_tip) * float(parameters.rib_chord_scale)
            outline, nodes = rib_template(scene, parameters, row)
            writer(folder / name, write_rib_dxf, outline, nodes, f"rib {rib} template, chord {chord * MM:.1f} mm",
                   allowance, f"rib {rib}")
            names.append(name)
    return names, panels
