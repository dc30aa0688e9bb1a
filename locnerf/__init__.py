"""locnerf: Monte Carlo localization of a camera in a radiance-field map.

Importing the package has no side effects on the process (no environment variables, no threads):
process-wide settings belong to the entry points (``cli.main``, the services' ``__main__``).
"""
