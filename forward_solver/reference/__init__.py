"""Independent references for validation, sharing no code with the force kernel: `closed_forms` (analytic rest
states of the paper's fabric law) and `independent_residual` (eq. 10-15 written again in plain numpy). Reached by
the tests and the validation report (`benchmarks/validation_report.py`); nothing in the solver imports them.
"""
