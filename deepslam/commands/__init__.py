"""Subcommands of ``deepslam``, one module each, discovered automatically.

A subcommand module defines:

- ``NAME``: the subcommand (``"eval"``),
- ``HELP``: one line for ``deepslam --help``,
- ``add_arguments(parser)``: fills an ``argparse.ArgumentParser``,
- ``run(args) -> int``: parses nothing more, calls the library and prints its report, importing the library
  inside (building the parser of every command, ``deepslam --help``, must not import numpy, torch or the
  simulator: that is the reason of every import inside a function of this package);
- optionally ``NEEDS(args) -> tuple[str, ...]``: the optional modules the run always needs, checked by
  ``deepslam.cli`` before any work.

Bad input raises :class:`core.errors.InputError`; ``deepslam.cli`` prints it as one line and exits 2.
"""
