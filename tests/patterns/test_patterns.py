"""Cut-ready patterns: the flat panels and rib templates, read back with ezdxf.

One small design point (NACA 2412, 5x32 grid: the equilibrium at a pressure
and two prestrains, as ``--evaluate`` writes it; the report's pattern path is
the same for an optimised design, whose ``success`` it reads) and its report
folder are shared by the tests. The files are read back with ezdxf
and checked against the design, not against themselves: the sewing
outlines' edges against `rib_design.cut_lengths` (0.1 mm, the issue's
tolerance), the cut line against the seam allowance, and the reference
lengths rebuilt from the drawn grid against the design's equilibrium (the
force residual of eq. 10-15 at the design's nodes, and a new solve from the
prestrain recovered from the drawing, within the solver's tolerance).
"""

import json
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

ezdxf = pytest.importorskip("ezdxf")

from matplotlib.path import Path as Polygon  # noqa: E402

from forward_solver import Bay, Fabric, Parameters, Result, Scene, solve_equilibrium  # noqa: E402
from forward_solver import forces as fk  # noqa: E402
from inverse_design.app import cli  # noqa: E402
from inverse_design.app.folder import ReportOptions, write_report  # noqa: E402
from inverse_design.app.cut_files import rib_mark_nodes  # noqa: E402
from support.reports import measured  # noqa: E402
from inverse_design.flat_layout import develop, layout_faults, offset_outline  # noqa: E402
from inverse_design.flat_panels import RIB_CHORDAL_ERROR, mounted_skin, rib_template  # noqa: E402
from inverse_design.rib_design import cut_lengths  # noqa: E402
from targets import naca  # noqa: E402

TARGET = naca("2412")
RTOL = 1e-8  # solve_equilibrium's default relative residual
ALLOWANCE = 12.0  # mm, not the default, so that the files are seen to follow the option


@pytest.fixture(scope="module")
def scene():
    return Scene(Bay.from_airfoil(TARGET, chord=1.0, rib_spacing=0.25, n_span=5, n_contour=32), Fabric())


@pytest.fixture(scope="module")
def design(scene):
    solution = solve_equilibrium(scene, Parameters(pressure=2e4, prestrain_span=0.02, prestrain_chord=0.01))
    assert solution.converged, solution.message
    return solution


@pytest.fixture(scope="module")
def folder(tmp_path_factory, scene, design):
    out = tmp_path_factory.mktemp("patterns") / "out"
    summary = write_report(out, measured(design, TARGET, scene), options=ReportOptions(seam_allowance_mm=ALLOWANCE))
    return out, summary


def _layer(doc, layer):
    return [np.asarray(e.get_points("xy"), np.float64) for e in doc.modelspace().query(f'LWPOLYLINE[layer=="{layer}"]')]


def _closed_lengths(points):
    return np.linalg.norm(np.roll(points, -1, axis=0) - points, axis=1)


def test_the_folder_lists_the_panels_and_rib_templates(folder):
    out, summary = folder
    names = {f"pattern_bay_0_{p}.{k}" for p in ("upper", "lower") for k in ("dxf", "svg")} | {"rib_0.dxf", "rib_1.dxf"}
    assert names <= set(summary["files"]) and set(summary["patterns"]["files"]) == names
    assert all((out / name).is_file() for name in names)
    record = json.loads((out / "summary.json").read_text())
    assert record["patterns"]["seam_allowance_mm"] == ALLOWANCE
    assert record["patterns"]["largest_length_error_m"] < 1e-9
    assert (out / "pattern_bay_0_upper.svg").read_text().startswith("<svg")


def test_every_dxf_passes_the_audit_in_millimetres_on_its_layers(folder):
    out, summary = folder
    for name in summary["patterns"]["files"]:
        if not name.endswith(".dxf"):
            continue
        doc = ezdxf.readfile(out / name)
        auditor = doc.audit()
        assert not auditor.has_errors and not auditor.fixes, (name, auditor.errors, auditor.fixes)
        assert doc.header["$INSUNITS"] == 4, name  # millimetres
        assert {"CUT", "SEW", "MARK"} <= {layer.dxf.name for layer in doc.layers}, name
        assert len(_layer(doc, "SEW")) == 1 and len(_layer(doc, "CUT")) == 1, name
        assert len(doc.modelspace().query('LWPOLYLINE[layer=="MARK"]')) >= 5, name
        texts = [t.dxf.text for t in doc.modelspace().query("TEXT")]
        assert any("1:1" in t for t in texts), name
    upper = ezdxf.readfile(out / "pattern_bay_0_upper.dxf").modelspace()
    texts = [t.dxf.text for t in upper.query("TEXT")]
    assert "WARP" in texts and any("bay 0 upper" in t for t in texts)
    assert any(t.startswith("LE seam") for t in texts)  # (the leading edge, named by its seam's label)


def test_the_sewing_outlines_are_the_design_cut_lengths(folder, scene, design):
    out, _ = folder
    cuts = cut_lengths(scene, design.parameters)
    contour, span = cuts["contour_edge_cut_m"] * 1000, cuts["span_edge_cut_m"] * 1000  # mm
    n_span, n_contour = scene.bay.n_span, scene.bay.n_contour
    j_le = int(np.argmin(np.asarray(scene.bay.contour_root)[:, 0]))
    panels = {"upper": np.arange(0, j_le + 1), "lower": np.r_[np.arange(j_le, n_contour), 0]}
    covered = np.zeros(n_contour, bool)
    for name, columns in panels.items():
        sew = _layer(ezdxf.readfile(out / f"pattern_bay_0_{name}.dxf"), "SEW")[0]
        m = len(columns)
        assert len(sew) == 2 * (m + n_span) - 4
        edges = columns[:-1]
        # the outline: root rib row, last fibre upward, tip rib row back, first fibre down
        expected = np.concatenate([contour[0, edges], span[:, columns[-1]], contour[-1, edges][::-1],
                                   span[:, columns[0]][::-1]])
        np.testing.assert_allclose(_closed_lengths(sew), expected, rtol=0, atol=0.1)
        assert np.max(np.abs(_closed_lengths(sew) - expected)) < 1e-6  # (it is exact to rounding)
        covered[edges] = True
    assert covered.all()  # every contour edge of the ribs is in one panel


def test_the_cut_line_lies_outside_the_sewing_line_at_the_allowance(folder):
    out, summary = folder
    for name in summary["patterns"]["files"]:
        if not name.endswith(".dxf"):
            continue
        doc = ezdxf.readfile(out / name)
        sew, cut = _layer(doc, "SEW")[0], _layer(doc, "CUT")[0]
        assert not Polygon(sew).contains_points(cut).any(), name

        def distances(points, outline):  # from each point to the closed outline's nearest edge
            a, b = outline, np.roll(outline, -1, axis=0)
            ab = b - a
            t = np.clip(np.einsum("pkd,kd->pk", points[:, None] - a, ab) / np.sum(ab * ab, axis=1), 0, 1)
            return np.min(np.linalg.norm(points[:, None] - (a + t[..., None] * ab), axis=-1), axis=1)

        assert np.min(distances(cut, sew)) >= ALLOWANCE * (1 - 1e-9), name
        midpoints = 0.5 * (sew + np.roll(sew, -1, axis=0))
        np.testing.assert_allclose(distances(midpoints, cut), ALLOWANCE, rtol=1e-9, err_msg=name)


def _rebuilt_reference(out, scene):
    """``(span (n_span - 1, n_contour), contour (n_span, n_contour))`` cut lengths, m, from the
    drawn grids (GRID: one polyline per contour node, in panel order) of the two panels."""
    n_span, n_contour = scene.bay.n_span, scene.bay.n_contour
    j_le = int(np.argmin(np.asarray(scene.bay.contour_root)[:, 0]))
    span = np.full((n_span - 1, n_contour), np.nan)
    contour = np.full((n_span, n_contour), np.nan)
    for name, columns in (("upper", np.arange(0, j_le + 1)), ("lower", np.r_[np.arange(j_le, n_contour), 0])):
        fibres = np.stack(_layer(ezdxf.readfile(out / f"pattern_bay_0_{name}.dxf"), "GRID"), axis=1) / 1000
        assert fibres.shape == (n_span, len(columns), 2)
        span[:, columns] = np.linalg.norm(fibres[1:] - fibres[:-1], axis=-1)
        contour[:, columns[:-1]] = np.linalg.norm(fibres[:, 1:] - fibres[:, :-1], axis=-1)
    assert np.isfinite(span).all() and np.isfinite(contour).all()
    return span, contour


def test_the_pattern_rebuilt_reproduces_the_design_equilibrium(folder, scene, design):
    out, _ = folder
    span, contour = _rebuilt_reference(out, scene)
    cuts = cut_lengths(scene, design.parameters)
    assert np.max(np.abs(span - cuts["span_edge_cut_m"])) < 1e-9
    assert np.max(np.abs(contour - cuts["contour_edge_cut_m"])) < 1e-9
    solution = design
    # 1. The design's nodes are an equilibrium of the fabric cut to the pattern: the relative force
    # residual (eq. 10-15) with the rebuilt reference lengths is within the solver's tolerance.
    physics = fk.static_physics(scene.physics(dynamic=False))
    with jax.enable_x64(True):
        params = scene.params(solution.parameters.as_floats())
        geometry = jax.tree_util.tree_map(jnp.asarray, scene.bay.geometry())
        ref = fk.prepare(geometry, params, physics)
        rebuilt = ref._replace(span_length=jnp.asarray(span), contour_length=jnp.asarray(contour))
        residual = float(fk.relative_residual(jnp.asarray(solution.nodes), rebuilt, params, physics))
        mounted = np.asarray(ref.nodes)
    assert residual <= RTOL and residual <= 2 * solution.residual
    # 2. Solved again: the prestrain recovered from the pattern (mounted length / pattern length - 1,
    # edge by edge) is uniform here, and the equilibrium solved from it is the design's.
    e_span = np.linalg.norm(mounted[1:] - mounted[:-1], axis=-1) / span - 1
    e_chord = np.linalg.norm(np.roll(mounted, -1, axis=1) - mounted, axis=-1) / contour - 1
    assert np.ptp(e_span) < 1e-9 and np.ptp(e_chord) < 1e-9
    again = solve_equilibrium(scene, solution.parameters.replace(prestrain_span=float(np.mean(e_span)),
                                                                prestrain_chord=float(np.mean(e_chord))))
    assert again.converged and again.residual <= RTOL
    # Two equilibria within RTOL of the same fabric: their nodes agree to well within 1e-6 chord.
    assert np.max(np.abs(again.nodes - solution.nodes)) < 1e-6 * scene.bay.chord


def test_develop_is_exact_where_a_strip_cannot_stay_a_rectangle():
    # A fan: span fibres of different cut lengths (as a prestrain varying along the contour gives)
    # and rows of different lengths; every edge is laid at its length, and a closed form checks the
    # angle choice: equal rows, equal fibres and right angles asked for give a rectangle.
    rng = np.random.default_rng(3)
    contour = 0.05 * (1 + 0.1 * rng.random((6, 9)))
    span = 0.04 * (1 + 0.1 * rng.random((5, 10)))
    flat = develop(contour, span)
    np.testing.assert_allclose(np.linalg.norm(np.diff(flat, axis=1), axis=-1), contour, rtol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(np.diff(flat, axis=0), axis=-1), span, rtol=1e-9)
    rectangle = develop(np.full((4, 5), 0.1), np.full((3, 6), 0.2))
    xs, ys = np.meshgrid(np.arange(6) * 0.1, np.arange(4) * 0.2)
    np.testing.assert_allclose(rectangle, np.stack([xs, ys], axis=-1), atol=1e-12)


def test_a_bay_whose_layout_runs_the_damping_down_develops_without_a_singular_solve():
    # Bay 10 of inverse_design/cases/wing_40_cells.toml at its design (1 kPa, 2.54% span prestrain):
    # the exact phase's damping fell until it was lost in rounding, and scipy's "Matrix is exactly
    # singular" warning reached the user's console (the step was then rejected, the layout exact).
    from forward_solver import Wing
    from inverse_design.flat_panels import bay_panels

    af = naca("4415")
    bay = Wing(airfoils=(af, af), chords=(2.3372, 2.3238), stations=(1.5, 1.65)).scenes(Fabric())[0]
    values = Parameters(pressure=1e3, prestrain_span=0.025357197747568918, prestrain_chord=0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        panels = bay_panels(bay, values.resolved(Fabric()), 10)
    assert [p.name for p in panels] == ["upper", "lower"]
    assert max(p.length_error for p in panels) < 1e-12  # m


def test_offset_outline_of_a_square_is_the_square_grown():
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    for points in (square, square[::-1]):  # either orientation
        grown = offset_outline(points, 0.1)
        assert sorted(map(tuple, np.round(grown, 12))) == sorted(
            map(tuple, np.round(np.array([[-0.1, -0.1], [1.1, -0.1], [1.1, 1.1], [-0.1, 1.1]]), 12)))


def test_a_layout_that_lies_over_itself_is_found():
    """`layout_faults` finds what edge lengths alone do not: none on a plain grid; the two cells of a
    column folded back over its neighbour; the crossings of an annular strip laid round 1.15 turns, every
    cell the same way round (none at 0.9 turns)."""
    x, y = np.meshgrid(np.arange(5.0), np.arange(3.0))
    grid = np.stack([x, y], axis=-1)  # (3, 5, 2)
    assert layout_faults(grid) == (0, 0)
    folded = grid.copy()
    folded[:, 4, 0] = 2.5  # the last column laid back between the third and the fourth
    assert layout_faults(folded)[0] == 2
    radius = np.array([1.0, 1.1])[:, None]
    for turns, crossed in ((0.9, False), (1.15, True)):
        angle = np.linspace(0.0, 2.0 * np.pi * turns, 37)
        strip = np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=-1)  # (2, 37, 2)
        folded, crossings = layout_faults(strip)
        assert folded == 0 and (crossings > 0) == crossed, (turns, crossings)


def test_a_failed_design_gets_no_pattern(folder, scene, design, tmp_path):
    from dataclasses import replace

    failed = replace(design, result=Result.max_steps_reached)  # (the flag the report reads)
    summary = write_report(tmp_path / "out", measured(failed, TARGET, scene))
    assert summary["results"]["success"] is False
    assert not [n for n in summary["files"] if n.startswith("pattern_") or n.endswith(".dxf")]
    assert "failed design" in summary["skipped"]["patterns"] and "patterns" not in summary
    assert not list((tmp_path / "out").glob("*.dxf"))
    assert "bay_0_cut_pattern.csv" in summary["files"]  # the table of lengths stays
    summary = write_report(tmp_path / "off", measured(design, TARGET, scene), options=ReportOptions(patterns=False))
    assert not list((tmp_path / "off").glob("*.dxf")) and "patterns" in summary["skipped"]


def test_a_negative_seam_allowance_is_refused_with_one_line(tmp_path, capsys, scene, design):
    code = cli.main(["--seam-allowance", "-5", "--n-span", "5", "--n-contour", "32", "--out", str(tmp_path / "o"),
                     "--no-compilation-cache"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert "--seam-allowance must be 0 mm or more" in err[0] and "got -5" in err[0]
    assert not (tmp_path / "o").exists()
    with pytest.raises(ValueError, match="seam allowance must be 0 mm or more"):
        write_report(tmp_path / "o", measured(design, TARGET, scene), options=ReportOptions(seam_allowance_mm=-1.0))
    assert not (tmp_path / "o").exists()


# --------------------------------------------------------------------------- rib templates and layers


def _segment_midpoints(outline):
    return 0.5 * (outline + np.roll(outline, -1, axis=0))


def test_the_rib_template_is_the_section_not_the_grid_polygon(folder):
    # 5x32 grid, chord 1 m: the grid's polygon is millimetres off the section at the nose and between nodes.
    # The drawn outline must be the section within 0.1 mm, at its points and between them (its chords).
    out, _ = folder
    for name in ("rib_0.dxf", "rib_1.dxf"):
        outline = _layer(ezdxf.readfile(out / name), "SEW")[0] / 1000.0  # m, chord 1 m: chord units
        assert np.max(np.abs(TARGET.distance(outline))) < 1e-9, name  # on the section
        chordal = np.max(np.abs(TARGET.distance(_segment_midpoints(outline))))
        assert chordal <= RIB_CHORDAL_ERROR * 1.05, (name, chordal)  # (the midpoint is probed: 5% for the rest)
        assert chordal <= 1e-4, name


def test_a_smaller_rib_of_the_same_section_reuses_the_larger_ones_points():
    # A wing's ribs share a section and differ in chord: the outline's points are kept by contour
    # parameter (`flat_panels.rib_outline`), and a smaller rib's parameters are among a larger one's
    # (halvings of one grid). Every outline is the one computed alone, to the bit.
    from inverse_design.flat_panels import rib_outline

    shape = np.array([0.01, -0.02, 0.005, 0.01])
    alone = [rib_outline(naca("2412"), chord, 0.9, 1.0, shape) for chord in (1.0, 0.4)]
    section = naca("2412")
    evaluated = []
    contour_points = section.contour_points

    def counted(t):
        evaluated.append(np.size(t))
        return contour_points(t)

    section.contour_points = counted
    large = rib_outline(section, 1.0, 0.9, 1.0, shape)
    assert sum(evaluated) > large.shape[0]  # (its probes between the points too)
    evaluated.clear()
    small = rib_outline(section, 0.4, 0.9, 1.0, shape)
    assert sum(evaluated) == 0 and small.shape[0] < large.shape[0]
    assert np.array_equal(large, alone[0]) and np.array_equal(small, alone[1])
    assert not np.array_equal(rib_outline(section, 0.4, 0.8, 1.0, shape), small)  # (another scale: its own)


def test_the_rib_attachment_marks_are_at_the_skins_nodes(folder, scene, design):
    out, _ = folder
    nodes = mounted_skin(scene, design.parameters)[0][:, [0, 2]] * 1000.0  # mm, the root rib's contour nodes
    doc = ezdxf.readfile(out / "rib_0.dxf")
    outline = _layer(doc, "SEW")[0]
    ticks = [line for line in _layer(doc, "MARK") if len(line) == 2]  # (the scale bar is one polyline)
    j_le = int(np.argmin(nodes[:, 0]))
    marked = rib_mark_nodes(len(nodes), j_le)
    assert len(ticks) == len(marked) and 0 in marked and j_le in marked
    np.testing.assert_allclose(np.array([t[-1] for t in ticks]), nodes[marked], rtol=0, atol=1e-9)
    # the nodes lie on the drawn outline (the same section), within its chordal error
    a, b = outline, np.roll(outline, -1, axis=0)
    ab = b - a
    t = np.clip(np.einsum("pkd,kd->pk", nodes[:, None] - a, ab) / np.sum(ab * ab, axis=1), 0, 1)
    gap = np.min(np.linalg.norm(nodes[:, None] - (a + t[..., None] * ab), axis=-1), axis=1)
    assert gap.max() <= RIB_CHORDAL_ERROR * 1000.0 * 1.05
    # each tick runs 5 mm (10 mm at the leading edge) inward from its node
    lengths = np.array([np.linalg.norm(t[-1] - t[0]) for t in ticks])
    np.testing.assert_allclose(lengths, [10.0 if j == j_le else 5.0 for j in marked], rtol=1e-9)
    assert Polygon(outline).contains_points(np.array([t[0] for t in ticks])).all()


def test_the_rib_template_says_which_line_is_the_part(folder):
    out, _ = folder
    texts = " | ".join(t.dxf.text for t in ezdxf.readfile(out / "rib_0.dxf").modelspace().query("TEXT"))
    assert "SEW (blue): the rib outline, the part" in texts
    assert f"CUT (red): {ALLOWANCE:g} mm outside, the seam allowance of a fabric rib, not the part" in texts


def test_the_panels_grid_layer_is_off_for_a_cutter(folder):
    out, summary = folder
    for name in summary["patterns"]["files"]:
        if name.endswith(".dxf"):
            layers = ezdxf.readfile(out / name).layers
            for layer in ("CUT", "SEW", "MARK"):
                assert layers.get(layer).is_on(), (name, layer)
            if name.startswith("pattern_"):
                assert layers.get("GRID").is_off(), name


@pytest.mark.parametrize("n_span, n_contour", [(17, 256), (9, 32)])
def test_a_designed_rib_template_is_the_designed_section(n_span, n_contour):
    # The default grid and chord, and a coarse one; a rib shape and thickness scale: the outline against
    # the designed section (`forward_solver.rib_section`, on 2001 points of the section: 1e-8 chord).
    from forward_solver import rib_section

    shape = np.array([0.01, -0.02, 0.015, 0.0, 0.01, 0.02])
    parameters = Parameters(pressure=1e4, prestrain_span=0.02, prestrain_chord=0.02, rib_thickness_scale=0.9,
                            rib_shape=shape)
    bay_scene = Scene(Bay.from_airfoil(TARGET, chord=1.0, rib_spacing=0.25, n_span=n_span, n_contour=n_contour))
    outline, nodes = rib_template(bay_scene, parameters, 0)
    designed = rib_section(TARGET, shape, 0.9, n_points=2001)
    assert np.max(np.abs(designed.distance(outline))) < 1e-6
    assert np.max(np.abs(designed.distance(_segment_midpoints(outline)))) <= 1e-4
    assert np.max(np.abs(designed.distance(nodes))) < 1e-6  # the skin's nodes lie on it too
