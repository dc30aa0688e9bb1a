"""Opening the map a command or service names (a map file or the procedural world), the views it
renders for single-image trials, and the keyframe index of its reference poses."""
