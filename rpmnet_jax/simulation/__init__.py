"""Simulated scanners with true poses: ``range_scans`` (a depth camera around a mesh), ``rooms`` (terrestrial
stations inside a room), ``sites`` (terrestrial stations along a town's streets)."""
