"""Cameras, rays for a batch of poses and pixels, samplers and volume rendering.

This package never imports :mod:`locnerf.field`: fields are passed in as callables. The package itself imports
nothing: import its modules (``locnerf.render.camera`` imports no torch, so the wire schemas load without it).
"""
