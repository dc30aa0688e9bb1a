"""Radiance-field map backends behind one protocol, and the map file."""
