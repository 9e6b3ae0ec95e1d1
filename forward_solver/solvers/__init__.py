"""The solvers: every way to reach rest, each plugged into one loop (`loop`) or one Newton iteration (`newton`);
the methods as values (`methods`, `chain`) and N bays (`bays`); docs/architecture.md names every module. The
modules import one another and `forward_solver.solve`, so this file imports nothing: import from the modules
(or from `forward_solver`).
"""
