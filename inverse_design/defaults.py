"""The defaults of a design, the command's and the library's alike: defined here once, without JAX.

The command reads them before it imports JAX (its options, `inverse_design.app.options`); the design
library builds its own defaults from them (`variables.DEFAULT_START`, `objectives.DEFAULT_OBJECTIVE`,
`settings.Layout`). The forward solver's default bay grid (`forward_solver.model.bay.N_SPAN`,
`N_CONTOUR`) is the same grid: the solver cannot import the design library, and a test holds them equal.
"""

__all__ = ["DESIGN_VARIABLES", "N_CONTOUR", "N_SPAN", "OBJECTIVE", "OBJECTIVES", "PRESSURE", "PRESTRAIN_CHORD",
           "PRESTRAIN_SPAN", "VARIABLES"]

#: Names an engineer may optimise (fields of `forward_solver.Parameters`; the fabric's stiffnesses are
#: material data, not manufacturing choices).
VARIABLES = ("pressure", "prestrain_span", "prestrain_chord", "rib_thickness_scale", "rib_chord_scale",
             "rib_shape", "cut_pattern")
#: What the command designs by default: the pressure and the rib thickness scale.
DESIGN_VARIABLES = ("pressure", "rib_thickness_scale")
#: The objectives (`objectives`; "robust": `tolerance.robust`), and the default: every row from rib to rib.
OBJECTIVES = ("mid_bay", "average", "worst", "robust")
OBJECTIVE = "average"
#: The start of a design: the internal pressure, Pa, and the prestrain of both fibre directions (2%).
PRESSURE = 1e4
PRESTRAIN_SPAN = 0.02
PRESTRAIN_CHORD = 0.02
#: Every bay's grid: nodes along the span (ribs included: fewer under-resolve the skin beside the ribs,
#: docs/design_studies.md) and around the contour.
N_SPAN = 17
N_CONTOUR = 64
