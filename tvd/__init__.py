"""The math library of time-varying-domain coverage (Xu & Diaz-Mercado).

Pure functions over numpy arrays: Voronoi cells clipped to S (``coverage``), the control
laws TVD-C and TVD-D1 (``control``), time-varying densities (``density``) and the
differential-drive kinematics that turn a planar velocity into wheel speeds (``drive``).
Imports numpy and scipy only; never zenoh, click, matplotlib or anything that does I/O
(``tests/test_layout.py`` checks).
"""
