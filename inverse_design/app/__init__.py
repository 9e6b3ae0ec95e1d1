"""The ``optimise-pressure`` application: options and case files, the run, the output folder.

Everything here is built on the design library (`inverse_design`) and the
forward solver; nothing in the library imports this package. The command is
`cli.main` (the ``optimise-pressure`` console script; ``python -m
inverse_design.app.cli``). See ``docs/architecture.md``.
"""
