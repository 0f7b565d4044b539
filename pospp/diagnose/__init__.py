"""Model-discrepancy workflow (docs/diagnose.md): predict, compare, name, add, iterate.

Modules: ``effects`` (library of candidate effects and their signatures on algorithm B's
velocity error), ``workflow`` (``diagnose`` -> ``Diagnosis``; ``diagnosis_columns``,
``candidate_columns``, ``leg_gap_columns``, ``residual_curve_columns`` for the tables),
``synthetic`` (survey flights whose truth is the strapdown solution, for tests and demos).
Nothing is imported here.
"""
