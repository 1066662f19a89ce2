"""Benchmarks behind `fixer4d bench NAME`: each module prints its table and writes JSON
(default folder benchmarks/results/). They measure; tests never time anything."""
