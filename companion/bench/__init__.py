"""The ablation bench (paper Table IV, Fig. 11-13): seeded random scenarios x planner variants.

    table.py    pure: one run -> one CSV row, rows <-> runs.csv, aggregate(rows) -> summary
    execute.py  flies scenarios x variants across processes, writes the failure gallery
    figures.py  violin (Fig. 13b) and per-scenario lines (Fig. 13a)
    cli.py      ``companion bench``
"""

from companion.bench.table import aggregate, read_runs_csv, write_runs_csv

__all__ = ["aggregate", "read_runs_csv", "write_runs_csv"]
