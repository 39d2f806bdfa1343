"""Worlds, routes, noise and pyrender rendering for `aslam record`."""
