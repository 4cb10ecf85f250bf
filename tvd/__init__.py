"""The math library of time-varying-domain coverage (Xu & Diaz-Mercado).

Pure functions over numpy arrays: Voronoi cells clipped to S (``coverage``), the control
laws TVD-C, TVD-D1 and TVD-DA, the default (``control``), time-varying densities
(``density``), the differential-drive kinematics that turn a planar velocity into wheel
speeds (``drive``), the collision safety filter (``safety``), convex-polygon geometry for
obstacles (``geometry``) and the shape checks of array arguments (``arrays``).
Imports numpy and scipy only; never zenoh, click, matplotlib or anything that does I/O
(``tests/test_layout.py`` checks).
"""
