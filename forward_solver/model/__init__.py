"""The model: what defines one simulation, without solving it.

`bay` (the skin's geometry and grid, `Bay`), `fabric` (`Fabric`), `scene`
(`Scene`: bay, fabric and the physics switches), `parameters` (`Parameters`:
the traced, differentiable inputs), `wing` (`Wing`: ribs along the span),
`cut_field` (the cut pattern along the contour) and `rib_shape` (the rib
contours' offset). The force kernel (`forward_solver.forces`) imports
`cut_field` and `rib_shape`, and `bay` imports the kernel, so this file
imports nothing: import from the modules.
"""
