"""Benchmarks behind `fixer4d bench NAME`: each module prints its table and writes JSON
(default folder benchmarks/results/). They measure; tests never time anything."""


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1 (a count of repeats, frames or iterations)."""
    import argparse

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a whole number >= 1") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value}: must be >= 1")
    return value
