"""locnerf: Monte Carlo localization of a camera in a radiance-field map.

Importing the package asks PyTorch's CPU allocator for transparent huge pages on large buffers
(``THP_MEM_ALLOC_ENABLE``, read by torch at its first allocation, so it must be set before any
tensor exists): a map build allocates ~100 MB gradient tensors every step, and faulting them in
4 kB pages cost 40-50 ms per step on the 2-core CPU (13 ms with huge pages; docs/MAPS.md). Set the
variable to 0 to opt out.
"""

import os

os.environ.setdefault("THP_MEM_ALLOC_ENABLE", "1")
