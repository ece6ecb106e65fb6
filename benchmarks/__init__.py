"""Benchmarks that print figures, each run from the repository's top as `python -m benchmarks.NAME`
(`--help` for its options). Not installed with the package: they measure the product, they are
not part of it. Tests assert behaviour; these print speed and load figures (docs/performance.md)."""
