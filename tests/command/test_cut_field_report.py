"""A wing with a cut field per bay: one overview figure of every bay's field (`wing_figures.plot_cut_fields`).

That a per-bay design's folder holds the figure (cut_pattern_overview.png) is checked by
tests/design/test_cut_field.py::test_the_command_designs_a_field_per_bay, on the run it makes anyway."""

import numpy as np

from inverse_design.app import wing_figures


def test_the_overview_shows_each_bay_and_fibre_on_one_scale():
    # 40 bays of 32 nodes, the span field rising with the bay and the contour field with the arc:
    # each image holds its own field, bays on the vertical axis, both on one colour scale.
    arc = np.tile(np.linspace(0.0, 1.0, 32, endpoint=False), (40, 1))
    span = np.repeat(np.linspace(0.01, 0.03, 40)[:, None], 32, axis=1)
    contour = 0.02 + 0.01 * np.sin(2 * np.pi * arc)
    fig = wing_figures.plot_cut_fields(arc, span, contour, leading_edge=0.5)
    images = [ax.collections[0] for ax in fig.axes[:2]]
    assert [ax.get_title() for ax in fig.axes[:2]] == ["span fibres", "contour fibres"]
    np.testing.assert_array_equal(images[0].get_array().reshape(40, 32), span)
    np.testing.assert_array_equal(images[1].get_array().reshape(40, 32), contour)
    assert images[0].get_clim() == images[1].get_clim() == (contour.min(), max(span.max(), contour.max()))
    assert fig.axes[0].get_ylim()[1] > 39 > 0 > fig.axes[0].get_ylim()[0]

