"""Evaluation of PoseidonSLAM runs: every metric and report, each defined once.

Services never import this package (they import only ``common``); the ``poseidon``
command, benchmarks and tests do.
"""
