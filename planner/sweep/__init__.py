"""Feasibility sweeps: many plans of one base scenario, varied along axes, run in isolated processes.

The package keeps the parts apart:

* :mod:`planner.sweep.spec`: the sweep description (pydantic schema, loading), pure.
* :mod:`planner.sweep.expand`: axes -> the list of ordinary scenarios (one per plan), pure.
* :mod:`planner.sweep.task`: what one plan process runs (scenario in, outcome dict out).
* :mod:`planner.sweep.results`: outcome -> result row, the resumable journal, CSV and Parquet files.
* :mod:`planner.sweep.run`: the executors (embedded process pool, Ray) and the sweep driver.
* :mod:`planner.sweep.plots`: the summary figures (matplotlib, kept out of the math).
"""
