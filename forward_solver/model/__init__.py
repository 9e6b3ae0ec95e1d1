"""The model: what defines one simulation, without solving it (`Bay`, `Fabric`, `Scene`, `Parameters`, `Wing`, the
cut field and the rib shape; docs/architecture.md). The force kernel (`forward_solver.forces`) imports `cut_field`
and `rib_shape`, and `bay` imports the kernel, so this file imports nothing: import from the modules.
"""
