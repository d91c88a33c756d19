"""End-to-end studies that use every layer: the stress study, the demo, the metrics cross-check.

Library logic, not command line: ``deepslam stress`` and ``make demo`` are thin wrappers around
:mod:`deepslam.studies.stress` and :mod:`deepslam.studies.demo`; bench/ results scripts import from here.
"""
