"""Segment tables from geometry: volume-controlled hyperelastic FEM on felupe (heavy, optional)."""
