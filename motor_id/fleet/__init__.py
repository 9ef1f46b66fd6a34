"""A fleet's recordings x motors as tasks on Dask distributed; per-motor histories and drift."""
