"""Every byte on disk: recordings, estimates, graph JSON."""
