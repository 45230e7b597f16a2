"""Benchmarks run by `flightrecon bench NAME`: one module per NAME exposing `add_arguments(parser)`
and `run(args) -> dict`. Speed is measured here, never by timed assertions in tests."""
