"""Fixtures shared with the corpus test: FMUs exported by pythonfmu and pythonfmu3."""

from tests.cli.test_corpus import arrays3_fmu, names2

__all__ = ["arrays3_fmu", "names2"]
