"""The Loc-NeRF particle filter: particles, motion and measurement models, resampling, annealing,
initialisation, recovery, the estimate, and the localizer that ties them together (no I/O).

The package imports nothing itself: import the modules (``locnerf.filter.localizer``). Its settings
(``measurement_config``, ``search_config``, ``annealing``) import no torch, so the wire schemas that hold them
load without it."""
