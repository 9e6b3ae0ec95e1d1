"""The progress of a design (a tqdm counter of wing solves on stderr, ticked once per iterate) and of a
marker's nesting (`nesting_bar`: seconds against its time limit)."""

from __future__ import annotations

import os
import sys

from tqdm import tqdm

__all__ = ["nesting_bar", "notify", "progress_bar"]


def _shape() -> dict:
    """tqdm's size keywords: the terminal's, or a fixed 80 x 24 where it reports no size (0 x 0: a
    pseudo-terminal nobody sized, as under `script`, where tqdm would print nothing at all)."""
    try:
        size = os.get_terminal_size(sys.stderr.fileno())
    except (AttributeError, ValueError, OSError):
        size = None
    return dict(dynamic_ncols=True) if size and size.lines and size.columns else dict(ncols=80, nrows=24)


def progress_bar(progress: bool, cap: int, name: str):
    """A tqdm counter on stderr: wing solves so far (one per iterate, every bay solved once) against the
    cap; a silent no-op when off.

    No percentage or ETA: the cap is an upper bound, not the expected count.
    """
    shape = _shape()
    return tqdm(total=cap, desc=name, unit="wing solve", disable=not progress, leave=False, **shape,
                bar_format="{desc}: wing solve {n_fmt} (cap {total_fmt}), {elapsed} elapsed, "
                           "{rate_inv_fmt}{postfix}")


def notify(bar, callback, method):
    """The per-iterate hook of a design by ``method`` (a `methods.Method`): tick the bar, show the
    objective (`methods.Method.shown`), call the user's callback."""

    def on_record(entry: dict) -> None:
        shown = method.shown(entry["objective"])
        if "jacobian" in entry:  # the Jacobian's bay blocks (gauss_newton: one pass of compressed tangents)
            shown += f", Jacobian {entry['jacobian']}"
        bar.set_postfix_str(shown, refresh=False)
        bar.update(1)
        if callback is not None:
            callback(entry)

    return on_record


def nesting_bar(progress: bool, seconds: float, panels: int):
    """A tqdm bar on stderr of a marker's nesting: seconds so far against its time limit (the search
    usually ends on its own before it); the caller shows the phase and the length so far as its postfix.
    A silent no-op when off."""
    return tqdm(total=round(float(seconds), 1), desc=f"nesting {panels} panels", unit="s", disable=not progress,
                leave=False, **_shape(), bar_format="{desc}: {n:.0f} of at most {total:.0f} s{postfix}")
