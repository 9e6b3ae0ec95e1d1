"""The ``optimise-pressure`` application: one case from options or a case file, one run path, the report.

`case.Case` (options and case files, checked once), `run.run_case` (the
run of a case; every call into the design library in `design`), the report
(`summary`, `measures`, `folder`, `formats`, `output_folder`, the figures
`bay_figures` and `wing_figures`, the cut files `cut_files`), and the
command's machinery (`cli`, `console`, `interrupts`, `workers`,
`resources`). Everything here is built on the design library
(`inverse_design`) and the forward solver; nothing in the library imports
this package. The command is `cli.main` (the ``optimise-pressure`` console
script; ``python -m inverse_design.app.cli``). See ``docs/architecture.md``.
"""
