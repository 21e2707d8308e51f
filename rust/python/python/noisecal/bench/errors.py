"""The benchmark's one error type: a bad input, named with its fix."""


class BenchError(ValueError):
    """A bad input to the benchmark (the message names it and the fix)."""
