"""The ablation bench (paper Table IV, Fig. 11-13) and the weight sweep: seeded random scenarios
x planner variants (x score weights), on a local process pool or a Dask cluster.

    table.py      pure: one run -> one CSV row, rows <-> runs.csv, aggregate(rows) -> summary
    executors.py  where runs execute: a local process pool or a Dask cluster, as one Executor
    execute.py    flies scenarios x variants (x score weights) on an executor, keeps the failure gallery
    weights.py    the score weights (w_h, w_d, w_s) as one value, and their grids
    sweep.py      pure: a weight sweep's rows -> per-set summary, paired comparison, verdict
    figures.py    violin (Fig. 13b), per-scenario lines (Fig. 13a), the weight sweep
    paper_tables.py  pure: the paper's Tables I-III and the reference mission varied as each does

``companion bench`` and ``companion sweep`` are in :mod:`companion.cli` (bench.py, sweep.py,
sweep_weights.py).
"""

from companion.bench.table import aggregate, read_runs_csv, write_runs_csv

__all__ = ["aggregate", "read_runs_csv", "write_runs_csv"]
