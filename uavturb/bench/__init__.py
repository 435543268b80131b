"""Benchmarks behind ``uavturb bench``: each prints figures (speed and memory targets are measured here, never by
timed tests)."""
