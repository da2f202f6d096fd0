"""The grid-wide refit in actuator tiles: the tiles on disk, serial or on Dask."""
