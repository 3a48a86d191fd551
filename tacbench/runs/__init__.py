"""The run directory: the contract between the trainers, the sweeps and the reports. Nothing
here knows about torch or TAC; every trainer (TAC and the baselines) writes through it::

    <out>/runs/<algo>/<env>/<variant>/seed<k>/
      config.json  status.json  eval.csv  train.csv  losses.csv  tensorboard/  checkpoint/

- ``planning``: where a run goes, and whether a command starts, resumes, skips or refuses it;
- ``locks``: one writer per run directory;
- ``files``: atomic JSON, row-by-row CSVs, the writer of one run (:class:`RunWriter`);
- ``clock``: a run's wall and CPU seconds (its share of its process's), summed over its sessions;
- ``provenance``: versions, git commit and host, as config.json records them;
- ``checkpoints``: checkpoint generations (durable writes, manifests, choosing what to resume);
- ``tensorboard``: event files of the same rows.

docs/results-schema.md describes every file, column and field.
"""

from tacbench.runs.clock import CpuShares, RunClock
from tacbench.runs.files import (
    EVAL_COLUMNS,
    TRAIN_COLUMNS,
    CsvLog,
    RunWriter,
    State,
    atomic_write_json,
    check_writable,
    ensure_writable,
    group_changes,
    now_iso,
    read_json,
)
from tacbench.runs.planning import (
    DirectoryPlan,
    Outcome,
    as_read_now,
    check_checkpoint,
    check_nothing_to_lose,
    check_results_folder,
    differing_fields,
    plan_run,
    plan_runs,
    planned_runs,
    read_status,
    run_directory,
)
from tacbench.runs.provenance import VERSIONED_PACKAGES, git_commit, package_versions, run_metadata

__all__ = [
    "EVAL_COLUMNS",
    "TRAIN_COLUMNS",
    "VERSIONED_PACKAGES",
    "CpuShares",
    "CsvLog",
    "DirectoryPlan",
    "Outcome",
    "RunClock",
    "RunWriter",
    "State",
    "as_read_now",
    "atomic_write_json",
    "check_checkpoint",
    "check_nothing_to_lose",
    "check_results_folder",
    "check_writable",
    "differing_fields",
    "ensure_writable",
    "git_commit",
    "group_changes",
    "now_iso",
    "package_versions",
    "plan_run",
    "plan_runs",
    "planned_runs",
    "read_json",
    "read_status",
    "run_directory",
    "run_metadata",
]
