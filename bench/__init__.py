"""Benchmarks of tocontrol_ros: `bench/run_all.py` writes BENCHMARKS.md."""
