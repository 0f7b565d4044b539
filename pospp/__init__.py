"""pospp: POS post-processing with double-strapdown online calibration (Liu & Fang 2012).

Conventions (the full sheet is docs/method.md)
----------------------------------------------
Frames: i inertial, e ECEF, n local NED, b body FRD, s sensor as logged (FLU for ROS),
a GNSS antenna. Vectors carry their frame (``v_n``, ``lever_b``); DCMs are destination-first
(``C_nb``: ``v_n = C_nb @ v_b``); quaternions are scalar-first ``[w, x, y, z]``.
Units: SI and radians in the numeric core; degrees, deg/h, ug and arcsec only at the edges,
always named in the suffix (``_deg``, ``_dph``, ``_ug``). Time: int64 ``time_ns`` in files,
float64 ``t_s`` from a per-run epoch in numeric code.
Errors are computed minus true: ``dv_n = v_hat - v``; the misalignment phi (NED) satisfies
``C_nb_hat = (I - [phi x]) C_nb``; sensors read ``true + bias``.
"""

__version__ = "0.1.0"
