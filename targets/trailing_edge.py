"""Sections with open and closed trailing edges brought to one form (:func:`common_trailing_edge`).

A skin between two ribs, and a wing of bays, runs one grid whose trailing-edge
seam is either one line (closed) or two with a base between them (open), so
its sections must share the form. The change of one section's gap is
:meth:`targets.Airfoil.with_trailing_edge` (a blend over the last
:data:`TRAILING_EDGE_BLEND` of chord).
"""

from __future__ import annotations

TRAILING_EDGE_BLEND = 0.05
"""Chord fraction ahead of the trailing edge over which :meth:`Airfoil.with_trailing_edge`
blends a change of the trailing-edge gap (the section ahead of it is kept)."""

TRAILING_EDGE_MODES = ("close", "open", "as-given")
"""How :func:`common_trailing_edge` brings sections with open and closed trailing
edges to one form."""

BLEND_NODES = 401  # nodes of the resampled contour that a trailing-edge blend is applied to


def common_trailing_edge(airfoils, mode: str = "close", labels=None,
                         blend: float = TRAILING_EDGE_BLEND) -> tuple[list, list[dict]]:
    """Sections brought to one trailing-edge form, open or closed (module docstring), and what was changed.

    NACA codes are closed; most real ``.dat`` files are open by 0.1-0.5% of chord.

    Modes:

    * ``"close"`` (the default): close every open trailing edge
      (:meth:`Airfoil.with_closed_trailing_edge`). A fabric wing's trailing
      edge is a seam where the upper and lower skins meet, so a shop builds
      it closed whatever the section's file says; closing moves the section
      by at most half the gap, only over the last ``blend`` of chord.
    * ``"open"``: open every closed trailing edge to the largest gap among
      the open ones (:meth:`Airfoil.with_trailing_edge`), for a wing whose
      trailing edge is a rigid (blunt) spar.
    * ``"as-given"``: change nothing; a mix raises ValueError naming a closed
      and an open section and the modes that fix it.

    Sections that already share a form are returned unchanged in every mode.

    Args:
        airfoils: the sections (:class:`Airfoil`).
        mode: one of :data:`TRAILING_EDGE_MODES`.
        labels: a name per section for the notes and messages (default: the
            airfoil names).
        blend: chord fraction of the blend.

    Returns:
        ``(sections, changes)``: the sections, and per changed one a dict with
        ``index``, ``label``, ``gap_before``, ``gap_after`` (chord units) and
        ``blend``.

    Raises:
        ValueError: for an unknown mode, or a mix with ``"as-given"``.
    """
    if mode not in TRAILING_EDGE_MODES:
        raise ValueError(f"trailing_edge must be one of {', '.join(TRAILING_EDGE_MODES)}, got {mode!r}")
    airfoils = list(airfoils)
    labels = [a.name for a in airfoils] if labels is None else list(labels)
    closed = [a.closed_te for a in airfoils]
    if all(closed) or not any(closed):
        return airfoils, []
    if mode == "as-given":
        i, j = closed.index(True), closed.index(False)
        raise ValueError(f"{labels[i]} has a closed trailing edge and {labels[j]} an open one (gap "
                         f"{airfoils[j].trailing_edge_gap:.3g} chord), and one skin cannot join the two: set "
                         f"trailing_edge (--trailing-edge) to close (close the open ones, the default) or open "
                         f"(open the closed ones to the largest gap)")
    gap = 0.0 if mode == "close" else max(a.trailing_edge_gap for a in airfoils)
    sections, changes = [], []
    for k, airfoil in enumerate(airfoils):
        if airfoil.closed_te == (mode == "close"):
            sections.append(airfoil)
            continue
        sections.append(airfoil.with_trailing_edge(gap, blend))
        changes.append({"index": k, "label": labels[k], "gap_before": airfoil.trailing_edge_gap,
                        "gap_after": gap, "blend": blend})
    return sections, changes