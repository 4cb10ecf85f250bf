"""Missions: what a run is asked to do (the scenario: how S(t) and the density move, where
the robots start) and what it leaves behind (the report: plots, CSV, summary). Used by the
coordinator and by ``covswarm sim`` alike; no I/O but files.
"""
