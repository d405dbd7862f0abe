"""``rig sweep``: one scenario over a grid or a random sample of overrides, on a Dask
cluster (a local process pool by default). ``spec`` makes the points, ``point`` runs one,
``engine`` distributes them, ``table`` and ``summary`` write the results."""
