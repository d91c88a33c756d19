"""Benchmarks: every figure the issues name, each against its baseline measured in the same run."""
