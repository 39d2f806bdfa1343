"""The application layer: what `aslam` does, as plain Python functions.

``estimate()``, ``score()``, ``import``, sweeps: each takes paths and typed configuration, reports
progress and warnings through callbacks and returns a typed result. It never touches the terminal,
so the CLI, ``bench/``, the tests and Dask workers call the same functions. Below it:
``data_formats`` (every byte on disk), ``core`` (the pure SLAM), ``recorder`` (worlds).
"""
