"""The statistical tier: final-return distributions and a test that tolerates noise.

A reference group is one ``tacbench run`` command trained with several seeds; each run's score
is its mean evaluation return over the last :data:`~tacbench.regress.specs.STAT_LAST`
evaluations. A check trains the same command with other seeds (a fresh sample from the same
distribution if nothing changed) and asks whether the fresh scores are lower than the
reference's with a one-sided permutation test on the difference of means, exact (every split of
the pooled scores). With the Bonferroni correction over the groups checked, a check of
unchanged code raises a false alarm with probability at most :data:`STAT_ALPHA` (seeds being
exchangeable). It is not gated on library versions: telling real drops from noise across
version changes is its purpose.
"""

from __future__ import annotations

import csv
import itertools
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from tacbench import runs
from tacbench.bootstrap import mean_difference
from tacbench.errors import TacbenchError
from tacbench.regress import manifest as mf
from tacbench.regress.outcome import Row, TierResult
from tacbench.regress.specs import STAT_ALPHA, STAT_GROUPS, STAT_LAST, StatGroup

Log = Callable[[str], None]
FloatArray = npt.NDArray[np.float64]
EXACT_LIMIT = 500_000  # more splits than this: a Monte Carlo p-value instead
MONTE_CARLO_DRAWS = 100_000
BOOTSTRAP_REPS = 10_000
TEST = (
    "one-sided permutation test of mean(fresh) < mean(reference) on the final scores, exact "
    "over every split of the pooled scores, Bonferroni-corrected over the groups checked"
)


def permutation_pvalue(reference: Sequence[float], fresh: Sequence[float]) -> float:
    """P(mean(fresh) - mean(reference) <= observed) when the labels are exchangeable.

    Exact when there are at most :data:`EXACT_LIMIT` ways to split the pooled scores, else a
    Monte Carlo estimate ``(hits + 1) / (draws + 1)`` with a fixed generator.
    """
    ref, new = np.asarray(reference, float), np.asarray(fresh, float)
    if ref.size < 2 or new.size < 2:
        raise ValueError("the permutation test needs at least two scores on each side")
    pooled, n, m = np.concatenate([ref, new]), ref.size + new.size, new.size
    observed = new.mean() - ref.mean()
    splits = math.comb(n, m)
    if splits <= EXACT_LIMIT:
        chosen = np.array(list(itertools.combinations(range(n), m)))
    else:
        rng = np.random.default_rng(0)
        chosen = np.argsort(rng.random((MONTE_CARLO_DRAWS, n)), axis=1)[:, :m]
    fresh_sums = pooled[chosen].sum(axis=1)
    diffs = fresh_sums / m - (pooled.sum() - fresh_sums) / (n - m)
    tolerance = 1e-9 * max(1.0, float(np.abs(pooled).max()))  # equal splits, summed differently
    hits = int(np.count_nonzero(diffs <= observed + tolerance))
    return hits / splits if splits <= EXACT_LIMIT else (hits + 1) / (MONTE_CARLO_DRAWS + 1)


def bootstrap_interval(reference: Sequence[float], fresh: Sequence[float]) -> tuple[float, float]:
    """95 % percentile interval of mean(fresh) - mean(reference) from rliable's bootstrap, each
    side resampled on its own (seed 0, :data:`BOOTSTRAP_REPS` replications)."""
    _, low, high = mean_difference(fresh, reference, BOOTSTRAP_REPS, seed=0)
    return low, high


def compare_scores(
    name: str, reference: Sequence[float], fresh: Sequence[float], alpha: float
) -> Row:
    """``drop`` when the test rejects at ``alpha``, else ``ok``; the detail says by how much."""
    p = permutation_pvalue(reference, fresh)
    low, high = bootstrap_interval(reference, fresh)
    old, new = float(np.mean(reference)), float(np.mean(fresh))
    relative = f", {(new - old) / abs(old):+.0%}" if old else ""
    detail = (
        f"mean {old:.1f} -> {new:.1f} ({new - old:+.1f}{relative}; 95% CI of the change "
        f"[{low:.1f}, {high:.1f}]); p = {p:.4f}, a drop if p < {alpha:.4f}"
    )
    return Row(
        name, f"{len(reference)} vs {len(fresh)} seeds", "drop" if p < alpha else "ok", detail
    )


def score(eval_csv: Path, last: int = STAT_LAST) -> float:
    """A run's final score: the mean of ``return_mean`` over its last ``last`` evaluations."""
    with eval_csv.open(newline="") as handle:
        returns = [float(row["return_mean"]) for row in csv.DictReader(handle)]
    if len(returns) < last:
        raise TacbenchError(f"{eval_csv} has {len(returns)} evaluations; the score needs {last}.")
    return float(np.mean(returns[-last:]))


def _seed_args(seeds: Sequence[int]) -> list[str]:
    return [arg for seed in seeds for arg in ("--seed", str(seed))]


def _train(
    args: Sequence[str], seeds: Sequence[int], out: Path, last: int, runner: mf.Runner
) -> tuple[dict[int, float], dict[int, str], mf.CommandResult]:
    """Train ``args`` with ``seeds``; the scores of the complete runs and the others' reasons."""
    result = runner([*args, *_seed_args(seeds)], out)
    scores, problems = {}, {}
    for directory in result.directories:
        seed = int(directory.name.removeprefix("seed"))
        status = runs.read_json(directory / "status.json")
        if status["state"] == "complete":
            scores[seed] = score(directory / "eval.csv", last)
        else:
            problems[seed] = f"{status['state']} at step {status['step']}: {status['reason']}"
    for seed in set(seeds) - set(scores) - set(problems):
        problems[seed] = f"no run directory (exit status {result.exit_code}): {result.last_line}"
    return scores, problems, result


def update_stat(
    reference: Path,
    work: Path,
    groups: Sequence[StatGroup] = STAT_GROUPS,
    log: Log = print,
    runner: mf.Runner = mf.subprocess_runner,
) -> Path:
    """Train every group with its reference seeds and write ``<reference>/stat``."""
    start = time.perf_counter()
    with mf.staged(reference, "stat") as staging:
        entries = []
        for group in groups:
            t0 = time.perf_counter()
            scores, problems, result = _train(
                group.args, group.reference_seeds, work / group.name, STAT_LAST, runner
            )
            if problems:
                raise TacbenchError(
                    f"reference group {group.name}: not every run completed "
                    f"({'; '.join(f'seed {s}: {p}' for s, p in sorted(problems.items()))})"
                )
            (staging / group.name).mkdir()
            for directory in result.directories:
                text = mf.without_clocks((directory / "eval.csv").read_text())
                (staging / group.name / f"{directory.name}-eval.csv").write_text(text)
            entries.append(
                {
                    "name": group.name,
                    "command": mf.command_line([*group.args, *_seed_args(group.reference_seeds)]),
                    "args": list(group.args),
                    "reference_seeds": list(group.reference_seeds),
                    "check_seeds": list(group.check_seeds),
                    "scores": {str(seed): value for seed, value in sorted(scores.items())},
                    "seconds": round(time.perf_counter() - t0, 1),
                }
            )
            log(
                f"{group.name}: mean score {np.mean(list(scores.values())):.1f} "
                f"({entries[-1]['seconds']} s)"
            )
        manifest = mf.provenance("stat", reference)
        manifest.update(
            score=f"mean eval return_mean over a run's last {STAT_LAST} evaluations",
            last=STAT_LAST,
            test=TEST,
            alpha=STAT_ALPHA,
            seconds=round(time.perf_counter() - start, 1),
            groups=entries,
        )
        return mf.publish(staging, manifest, reference, "stat")


def check_stat(
    reference: Path,
    work: Path,
    names: Sequence[str] = (),
    log: Log = print,
    runner: mf.Runner = mf.subprocess_runner,
) -> TierResult:
    """Train each recorded group (all, or those in ``names``) with its check seeds and test the
    fresh scores against the recorded ones."""
    start, manifest = time.perf_counter(), mf.read_manifest(reference, "stat")
    notes = [mf.provenance_note(manifest), f"test: {manifest['test']}"]
    differences = mf.environment_differences(manifest["environment"], mf.environment())
    if differences:
        notes.append(f"made with {'; '.join(differences)} (this tier allows that)")
    entries: list[dict[str, Any]] = mf.select(manifest["groups"], names, reference)
    alpha = manifest["alpha"] / len(entries)
    rows = []
    for entry in entries:
        t0 = time.perf_counter()
        fresh, problems, _ = _train(
            entry["args"], entry["check_seeds"], work / entry["name"], manifest["last"], runner
        )
        log(
            f"{entry['name']}: trained {len(entry['check_seeds'])} seeds in "
            f"{time.perf_counter() - t0:.0f} s"
        )
        for seed, problem in sorted(problems.items()):
            rows.append(Row(entry["name"], f"seed {seed}", "missing", problem))
        if len(fresh) < 2:
            continue
        recorded = [float(v) for v in entry["scores"].values()]
        rows.append(compare_scores(entry["name"], recorded, list(fresh.values()), alpha))
    return TierResult(
        "stat",
        str(reference / "stat"),
        tuple(rows),
        tuple(notes),
        seconds=time.perf_counter() - start,
    )
