"""Inverse design: choose pressure and prestrain so the inflated skin matches a target.

Public names::

    section_errors

The optimiser (``optimise_pressure``, ``DesignResult``) and the full
``optimise-pressure`` command arrive with the gradient work; until then the
command evaluates the default case (see ``inverse_design.cli``).
"""

from .objectives import section_errors as section_errors

__all__ = ["section_errors"]
