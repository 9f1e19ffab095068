"""Benchmark harness of clraster (`clraster bench`; results and docs in the repository's
bench/ folder, see bench/README.md)."""
