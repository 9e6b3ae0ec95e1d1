"""The shop's marker (`inverse_design.marker`): the built-in 3-bay wing's panels nested on a roll, checked
with exact polygon tests of our own (`support.geometry`), not the nester's word.

The panels are the command's, laid out at the case's starting cut lengths on the small grid (no solve: the
layout needs the mounted skin and the cut lengths only). Each nesting runs on a short time limit: the
checks hold for any marker the nester returns, converged or stopped.
"""

import numpy as np
import pytest

from inverse_design.app.case import Case
from inverse_design.app.case_file import EXAMPLE_CASE
from inverse_design.flat_panels import bay_panels
from inverse_design.marker import CLEARANCE_MM, MarkerRequest, cut_outline, nest_panels
from support.cases import SMALL
from support.geometry import area, distance, overlap

WIDTH, GAP, ALLOWANCE = 1400.0, 5.0, 10.0


def _panels(*arguments):
    case = Case.from_arguments(["--config", str(EXAMPLE_CASE), *SMALL, *arguments, "--out", "unused"])
    scenes = case.wing.scenes(case.fabric, n_span=5, n_contour=32)
    return [panel for k, scene in enumerate(scenes) for panel in bay_panels(scene, case.start, bay=k)]


@pytest.fixture(scope="module")
def panels():
    return _panels()


@pytest.fixture(scope="module")
def marker(panels):
    return nest_panels(panels, MarkerRequest(roll_width_mm=WIDTH, gap_mm=GAP, seconds=4),
                       seam_allowance_mm=ALLOWANCE)


def test_every_panel_lies_once_on_the_roll(panels, marker):
    assert sorted((p.bay, p.name) for p in marker.pieces) == sorted((p.bay, p.name) for p in panels)
    assert len(marker.pieces) == 6


def test_no_two_cut_outlines_overlap_and_each_pair_keeps_the_gap(marker):
    pieces = marker.pieces
    for a in range(len(pieces)):
        for b in range(a + 1, len(pieces)):
            first, second = pieces[a].cut, pieces[b].cut
            assert not overlap(first, second), (pieces[a].bay, pieces[a].name, pieces[b].bay, pieces[b].name)
            assert distance(first, second) >= GAP - 0.01


def test_every_outline_lies_within_the_roll_and_the_length_used(marker):
    for piece in marker.pieces:
        assert piece.cut[:, 0].min() >= 0.5 * GAP - 0.01 and piece.cut[:, 0].max() <= WIDTH - 0.5 * GAP + 0.01
        assert piece.cut[:, 1].min() >= 0.5 * GAP - 0.01
        assert piece.cut[:, 1].max() <= marker.length_mm - 0.5 * GAP + CLEARANCE_MM + 0.01
    # the length used ends half a gap beyond the farthest outline
    far = max(p.cut[:, 1].max() for p in marker.pieces)
    assert far + 0.5 * GAP <= marker.length_mm + 1e-6 <= far + 0.5 * GAP + 2 * CLEARANCE_MM + 0.01


def test_each_outline_is_its_pattern_outline_moved_or_turned_half_a_turn(marker):
    for piece in marker.pieces:
        assert piece.rotation in (0.0, 180.0)  # the warp along the span: along the roll
        cut = cut_outline(piece.panel, ALLOWANCE)
        turned = cut if piece.rotation == 0.0 else -cut  # (a half turn, never a mirror)
        np.testing.assert_allclose(piece.cut, turned + (piece.cut[0] - turned[0]), atol=0.01)


def test_the_utilisation_is_the_panels_area_over_the_roll_used(marker):
    panel_area = sum(area(p.cut) for p in marker.pieces)
    assert marker.utilisation == pytest.approx(panel_area / (WIDTH * marker.length_mm), rel=1e-3)
    summary = marker.summary()
    assert summary["panels"] == 6 and summary["roll_width_mm"] == WIDTH and summary["nester"] == "sparrow"
    assert summary["ended"] in ("converged", "time limit") and 0 < summary["seconds"] < 30


def test_the_shelf_layout_keeps_the_same_rules(panels):
    shelf = nest_panels(panels, MarkerRequest(roll_width_mm=WIDTH, gap_mm=GAP, nester="shelf"),
                        seam_allowance_mm=ALLOWANCE)
    assert shelf.ended == "shelf" and len(shelf.pieces) == 6
    assert not any(overlap(a.cut, b.cut) for k, a in enumerate(shelf.pieces) for b in shelf.pieces[k + 1:])
    assert nest_panels(panels, MarkerRequest(roll_width_mm=WIDTH, gap_mm=GAP, nester="shelf"),
                       seam_allowance_mm=ALLOWANCE).length_mm == shelf.length_mm  # (the same every run)


def test_a_warp_along_the_chord_turns_every_panel_a_quarter():
    panels = _panels("--warp", "chord")[:2]  # the root bay's two panels
    assert {p.warp for p in panels} == {"chord"}
    marker = nest_panels(panels, MarkerRequest(roll_width_mm=WIDTH, gap_mm=GAP, warp="chord", seconds=2),
                         seam_allowance_mm=ALLOWANCE)
    for piece in marker.pieces:
        assert piece.rotation in (90.0, 270.0)
        cut = cut_outline(piece.panel, ALLOWANCE)
        turned = np.stack([-cut[:, 1], cut[:, 0]], axis=1) * (1 if piece.rotation == 90.0 else -1)
        np.testing.assert_allclose(piece.cut, turned + (piece.cut[0] - turned[0]), atol=0.01)
        # the panel's span (its chord-wise rows' stack) lies across the roll: narrow; its contour along it
        assert np.ptp(piece.cut[:, 0]) < np.ptp(piece.cut[:, 1])
    assert not overlap(marker.pieces[0].cut, marker.pieces[1].cut)


@pytest.mark.parametrize("fields, message", [
    (dict(roll_width_mm=0.0), "roll_width_mm must be a width in mm above 0"),
    (dict(roll_width_mm=20_000.0), "roll_width_mm must be a width in mm above 0 and at most 10000"),
    (dict(roll_width_mm=1400.0, gap_mm=-1.0), "gap_mm must be 0 mm or more"),
    (dict(roll_width_mm=1400.0, gap_mm=1400.0), "gap_mm must be 0 mm or more and less than the roll's width"),
    (dict(roll_width_mm=1400.0, warp="diagonal"), "warp must be one of span, chord"),
], ids=["zero", "absurd", "negative-gap", "gap-as-wide", "warp"])
def test_a_request_that_makes_no_sense_is_refused(fields, message):
    with pytest.raises(ValueError, match=message):
        MarkerRequest(**fields)


def test_a_roll_narrower_than_the_widest_panel_names_it(panels):
    with pytest.raises(ValueError, match=r"the bay 0 (upper|lower) panel needs 1\d\d\d\.\d mm across the roll"):
        nest_panels(panels, MarkerRequest(roll_width_mm=900.0), seam_allowance_mm=ALLOWANCE)
