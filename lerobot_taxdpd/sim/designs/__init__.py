"""Procedural geometry of the benchmarks' objects and fixtures, and their train/test parameter spaces."""
