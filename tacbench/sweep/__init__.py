"""``tacbench sweep``: the paper's grids on one machine, a Ray cluster or Slurm, idempotent and
crash-proof (docs/sweep.md). Nothing is imported here, so the CLI can read the preset names
without loading torch or Gymnasium.

- :mod:`~tacbench.sweep.presets`: the grids, each value with its source, and narrowing;
- :mod:`~tacbench.sweep.plan`: runs, their state on disk, actions and units of work;
- :mod:`~tacbench.sweep.driver`: the loop (schedule, record failures, retry, summarize);
- :mod:`~tacbench.sweep.until_decided`: ``--until-decided``, the driver interim by interim until
  AdaStop decides each task's comparisons;
- :mod:`~tacbench.sweep.executors`: a local process pool, or Ray tasks;
- :mod:`~tacbench.sweep.slurm`: Slurm job arrays through submitit;
- :mod:`~tacbench.sweep.worker`: what a worker process, Ray task or Slurm job runs;
- :mod:`~tacbench.sweep.state`, :mod:`~tacbench.sweep.summary`, :mod:`~tacbench.sweep.cost`,
  :mod:`~tacbench.sweep.progress`: failure history and lock, texts, cost estimate, display.
"""

# --group: what the TAC members of one unit may differ in (here: the CLI imports it at start-up)
GROUPS = ("task", "seeds", "none")
# --executor: where units run (here: the CLI imports it at start-up)
EXECUTORS = ("local", "ray", "slurm")
