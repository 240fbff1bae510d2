"""Sweeps: any experiment over a parameter grid, on a local process pool or a Dask cluster.

`grid` parses `--grid NAME=VALUES`, `knobs` types and validates the names, `experiments` holds
each experiment's knobs and cell (one single run), `runner` runs the cells on any
`concurrent.futures.Executor` and appends each to `DIR/cells.jsonl`, `engine` opens the
executor, `report` draws the maps.
"""
