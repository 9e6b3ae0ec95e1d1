"""The report's file formats: the skin as OBJ and STL, the equilibrium as ``.npz``, Selig ``.dat``, cut lengths as CSV.

Each function writes one file (`write_obj`, `write_stl`, `write_npz`,
`write_selig`, `write_cut_pattern`); `bay_arrays` and `wing_arrays` are the
contents of ``equilibrium.npz`` (one bay in full) and ``wing.npz`` (every
bay stacked), both written by `write_npz`. The output folder they go into
is `output_folder`'s.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..rib_design import cut_lengths
from . import interrupts
from .measures import chords_and_stations
from .summary import shared_names

__all__ = ["bay_arrays", "wing_arrays", "write_cut_pattern", "write_npz", "write_obj", "write_selig", "write_stl"]


def _quads(n_span: int, n_contour: int, periodic: bool) -> np.ndarray:
    """``(n_quads, 4)`` zero-based node indices of the grid's cells, counter-clockwise seen from outside."""
    index = np.arange(n_span * n_contour).reshape(n_span, n_contour)
    j = np.arange(n_contour if periodic else n_contour - 1)
    j1 = (j + 1) % n_contour
    # (i, j) -> (i+1, j) -> (i+1, j+1) -> (i, j+1): the normal e1 x e2 points out of the section.
    quads = np.stack([index[:-1][:, j], index[1:][:, j], index[1:][:, j1], index[:-1][:, j1]], axis=-1)
    return quads.reshape(-1, 4)


def write_obj(path, nodes, periodic: bool, name: str = "skin") -> Path:
    """Write the skin as a Wavefront OBJ: one vertex per node, one quad per cell.

    Args:
        path: file to write.
        nodes: ``(n_span, n_contour, 3)`` m.
        periodic: close the contour (a wing section) with a last column of quads.
        name: object name in the file.

    Returns:
        The path. Vertex ``1 + i * n_contour + j`` is node ``(i, j)``; faces
        wind counter-clockwise seen from outside the wing.
    """
    nodes = np.asarray(nodes, dtype=np.float64)
    n_span, n_contour, _ = nodes.shape
    quads = _quads(n_span, n_contour, periodic) + 1
    lines = [
        "# inflatable-wing equilibrium skin; units: metres (x chordwise, y spanwise, z up)",
        f"# grid {n_span} x {n_contour} nodes (span x contour); vertex 1 + i*{n_contour} + j is node (i, j)",
        f"o {name}",
    ]
    # (Python floats and ints, not NumPy scalars: half the time, the same text)
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in nodes.reshape(-1, 3).tolist()]
    lines += [f"f {a} {b} {c} {d}" for a, b, c, d in quads.tolist()]
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path


def write_stl(path, nodes, periodic: bool) -> Path:
    """Write the skin as a binary STL (two triangles per cell, outward normals), metres."""
    nodes = np.asarray(nodes, dtype=np.float64)
    n_span, n_contour, _ = nodes.shape
    quads = _quads(n_span, n_contour, periodic)
    flat = nodes.reshape(-1, 3)
    triangles = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    corners = flat[triangles]  # (n, 3, 3)
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
    record = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    data = np.zeros(len(triangles), dtype=record)
    data["normal"], data["corners"] = normals, corners
    header = b"inflatable-wing equilibrium skin, units: metres".ljust(80, b" ")
    path = Path(path)
    with open(path, "wb") as f:
        f.write(header)
        f.write(np.uint32(len(triangles)).tobytes())
        f.write(data.tobytes())
    return path


def write_npz(path, arrays: dict) -> Path:
    """``np.savez_compressed(path, **arrays)`` (no pickles), never cut short by a stop of the command.

    A Ctrl-C or SIGTERM that lands while a member of the zip file is being
    closed leaves its write handle open; closing the zip file then raises
    ValueError ("Can't close the ZIP file while there is an open writing
    handle") in place of the stop, and the run ended with exit 2. The write
    runs as an `interrupts.deferred` section: a stop arriving in it is raised
    when the file is complete.
    """
    path = Path(path)
    with interrupts.deferred(), open(path, "wb") as f:
        np.savez_compressed(f, **arrays)
    interrupts.check()
    return path


def _history(result, names) -> tuple[np.ndarray, np.ndarray]:
    """``(objective, values)`` of the optimiser's iterates: ``(n_iterates,)`` and ``(n_iterates, components)``
    of the variables ``names`` (a vector variable takes a column per component)."""
    rows = [np.concatenate([np.ravel(h["values"][n]) for n in names]) for h in result.history]
    return (np.array([h["objective"] for h in result.history], dtype=np.float64),
            np.array(rows, dtype=np.float64).reshape(len(rows), -1))


def bay_arrays(solution, target, scene, deviation: np.ndarray, result=None) -> dict:
    """The arrays of one bay's ``equilibrium.npz`` (the bay in full).

    Arrays: ``nodes`` (n_span, n_contour, 3) m; ``tension_span``,
    ``tension_chord`` (n_span - 1, n_cells) N/m; ``wrinkled`` (same, bool);
    ``fixed`` (n_span, n_contour) bool; ``deviation`` (n_span, n_contour)
    signed normal distance from the target, fraction of chord
    (`measures.wing_deviation`); ``target_xz`` (n, 2) the chord-normalised
    target; ``mid_bay_section`` and ``rib_section`` (n_contour, 2) x-z in m;
    scalars ``pressure`` (Pa), ``prestrain`` (span, chord),
    ``rib_thickness_scale``, ``rib_chord_scale``, ``stiffness`` (span, chord)
    N/m, ``chord`` and ``rib_spacing`` (m); ``rib_shape`` (2 K coefficients,
    empty for an unshaped rib); the cut lengths of `rib_design.cut_lengths`
    (``contour_edge_cut`` (n_span, n_edges), ``span_edge_cut`` (n_span - 1,
    n_contour), m); with the design ``result`` (None for a single
    equilibrium) ``variables`` (names), ``history_objective`` and
    ``history_values`` (iterate x component; a rib shape takes 2 K columns).
    """
    bay = scene.bay
    values = solution.parameters
    arrays = dict(
        nodes=np.asarray(solution.nodes), tension_span=np.asarray(solution.tension_span),
        tension_chord=np.asarray(solution.tension_chord), wrinkled=np.asarray(solution.wrinkled, bool),
        fixed=np.asarray(bay.fixed, bool), deviation=np.asarray(deviation, np.float64),
        target_xz=np.stack([np.asarray(target.x), np.asarray(target.z)], axis=-1),
        mid_bay_section=solution.section(0.5), rib_section=solution.section(0.0),
        pressure=np.float64(values.pressure),
        prestrain=np.array(values.prestrain, dtype=np.float64),
        rib_thickness_scale=np.float64(values.rib_thickness_scale),
        rib_chord_scale=np.float64(values.rib_chord_scale),
        stiffness=np.array(values.stiffness, dtype=np.float64),
        chord=np.float64(bay.chord), rib_spacing=np.float64(bay.rib_spacing),
        target_name=np.array(str(target.name)),
        rib_shape=np.zeros(0) if values.rib_shape is None else np.asarray(values.rib_shape, np.float64),
    )
    cuts = cut_lengths(scene, values)
    arrays.update(contour_edge_cut=cuts["contour_edge_cut_m"], span_edge_cut=cuts["span_edge_cut_m"])
    if result is not None:
        names = list(result.variables)
        arrays["variables"] = np.array(names, dtype=str)
        arrays["history_objective"], arrays["history_values"] = _history(result, names)
    return arrays


def wing_arrays(result, solutions: list, deviation: np.ndarray) -> dict:
    """The arrays of ``wing.npz``: every bay stacked, ``nodes`` (n_bays, n_span, n_contour, 3) m (each bay in
    its own frame, root rib at y = 0), tensions N/m, wrinkled cells, ``deviation`` from the row targets
    (`measures.wing_deviation`), weights, stations, chords, result codes, residuals, the parameters, the
    targets' names, the shared variables' history, and the per-rib shapes and per-bay cut fields."""
    sol, params, per_bay = result.wing_solution, result.parameters, result.per_bay
    shared = shared_names(result)
    chords, stations = chords_and_stations(result)
    objective, history = _history(result, shared) if result.history else (np.zeros(0), np.zeros((0, 0)))
    return dict(
        nodes=np.stack([s.nodes for s in solutions]),
        tension_span=np.stack([s.tension_span for s in solutions]),
        tension_chord=np.stack([s.tension_chord for s in solutions]),
        wrinkled=np.stack([np.asarray(s.wrinkled, bool) for s in solutions]),
        deviation=deviation, weights=np.asarray(per_bay.weights),
        stations=np.asarray(stations, np.float64), chords=np.asarray(chords, np.float64),
        result=np.asarray(sol.result), residual=np.asarray(sol.residual, np.float64),
        pressure=np.float64(params.pressure), prestrain=np.array(params.prestrain, np.float64),
        rib_thickness_scale=np.float64(params.rib_thickness_scale), rib_chord_scale=np.float64(params.rib_chord_scale),
        target_names=np.array([t.name for t in per_bay.targets], dtype=str),
        variables=np.array(list(shared), dtype=str), history_objective=objective, history_values=history,
        rib_shapes=np.zeros((0, 0)) if per_bay.rib_shapes is None else np.asarray(per_bay.rib_shapes),
        cut_patterns=np.zeros((0, 0)) if per_bay.cut_patterns is None else np.asarray(per_bay.cut_patterns))


def write_selig(path, airfoil, comment: str = "") -> Path:
    """Write a chord-normalised `targets.Airfoil` as a Selig ``.dat`` file (name line, then x z).

    Points run in the airfoil's own (Selig) order: trailing edge, upper
    surface, leading edge, lower surface. `targets.load_airfoil` reads it
    back.
    """
    name = " ".join(str(airfoil.name).split()) or "airfoil"
    lines = [name + (f"  ({comment})" if comment else "")]
    lines += [f"{x: .8f} {z: .8f}" for x, z in zip(np.asarray(airfoil.x), np.asarray(airfoil.z))]
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path


def write_cut_pattern(path, scene, parameters) -> Path:
    """Write the fabric's cut lengths (`rib_design.cut_lengths`) as CSV, one row per contour node.

    Columns: ``j`` (contour node), ``surface`` (upper/lower, Selig order),
    ``x_over_chord`` (at the root rib), ``arc_cut_root_m`` and
    ``arc_cut_mid_m`` (cut length along the contour from the trailing edge
    to the node, at the root rib's row and at mid-bay), ``span_cut_m`` (cut
    length of the span fibre through the node, rib to rib),
    ``span_mounted_m`` (its mounted length), ``span_prestrain`` (the local
    prestrain of that span fibre) and ``contour_prestrain`` (that of the
    contour edge from the node to the next; both the uniform prestrains
    unless a cut pattern, `forward_solver.model.cut_field`, varies them). The
    ``# `` header lines give the prestrains and each row's cut perimeter.
    """
    cuts = cut_lengths(scene, parameters)
    bay = scene.bay
    contour = cuts["contour_edge_cut_m"]
    mid = bay.n_span // 2
    arc_root = np.concatenate([[0.0], np.cumsum(contour[0])])[: bay.n_contour]
    arc_mid = np.concatenate([[0.0], np.cumsum(contour[mid])])[: bay.n_contour]
    x = np.asarray(bay.contour_root[:, 0])
    j_le = int(np.argmin(x))
    field = ("" if parameters.cut_pattern is None else
             f" plus a cut pattern of {np.size(parameters.cut_pattern) // 2} terms per direction (local "
             "prestrain in the last two columns)")
    lines = [f"# cut lengths of the fabric: reference length = mounted length / (1 + prestrain), "
             f"prestrain span {float(parameters.prestrain_span):.6g}, chord {float(parameters.prestrain_chord):.6g}"
             + field,
             f"# cut perimeter (trailing edge around to trailing edge): root rib "
             f"{cuts['contour_cut_m'][0]:.6f} m, mid-bay {cuts['contour_cut_m'][mid]:.6f} m, tip rib "
             f"{cuts['contour_cut_m'][-1]:.6f} m",
             "j,surface,x_over_chord,arc_cut_root_m,arc_cut_mid_m,span_cut_m,span_mounted_m,span_prestrain,"
             "contour_prestrain"]
    contour_prestrain = cuts["contour_prestrain"]  # a flat panel's last node takes its last edge's
    contour_prestrain = np.concatenate([contour_prestrain, contour_prestrain[-1:]])[: bay.n_contour]
    for j in range(bay.n_contour):
        surface = "upper" if j <= j_le else "lower"
        lines.append(f"{j},{surface},{x[j]:.6f},{arc_root[j]:.6f},{arc_mid[j]:.6f},"
                     f"{cuts['span_cut_m'][j]:.6f},{cuts['span_mounted_m'][j]:.6f},"
                     f"{cuts['span_prestrain'][j]:.6g},{contour_prestrain[j]:.6g}")
    path = Path(path)
    path.write_text("\n".join(lines) + "\n")
    return path

