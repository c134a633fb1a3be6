"""Benchmarks (`warpcoil bench accuracy|stress`): numbers for BENCHMARKS.md, not tests."""
