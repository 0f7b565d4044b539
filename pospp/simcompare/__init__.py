"""Measured flight versus its simulation: statistics, effect library, step-wise model fit.

Numeric only (no I/O): :mod:`pospp.compare_sim` reads a run and writes its outputs.
docs/compare_sim.md describes the workflow.
"""
