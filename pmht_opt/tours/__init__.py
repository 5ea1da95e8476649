"""Straight-line tours through discs: the close-enough TSP and its multi-vehicle generalisation."""
