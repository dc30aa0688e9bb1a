"""Maps from captures nobody posed: structure from motion (pycolmap), metric scale and gravity."""
