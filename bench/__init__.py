"""Timing and figure scripts, each run as a module from the repository's root (python -m bench.suite)."""
