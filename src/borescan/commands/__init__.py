"""Subcommands of the ``borescan`` console command, one module each.

Each module defines ``NAME`` (the subcommand), ``HELP`` (one line), ``add_arguments(parser)``
and ``run(args) -> int`` (the exit code). :mod:`borescan.cli` finds them by listing this package,
so a new subcommand is a new module here and nothing else.
"""
