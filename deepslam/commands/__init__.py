"""Subcommands of ``deepslam``, one module each, discovered automatically.

A subcommand module defines:

- ``NAME``: the subcommand (``"eval"``),
- ``HELP``: one line for ``deepslam --help``,
- ``add_arguments(parser)``: fills an ``argparse.ArgumentParser``,
- ``run(args) -> int``: does the work, importing heavy libraries lazily inside.

Bad input raises :class:`core.errors.InputError`; ``deepslam.cli`` prints it as one line and exits 2.
"""
