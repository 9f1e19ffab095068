"""Benchmark harness of clraster (installed as ``clraster.bench``; see bench/README.md)."""
