"""The report's verdict on P(X > Y): a stratified permutation test of the probability of
improvement.

The report shows P(X > Y) with a bootstrap interval (:mod:`tacbench.report.stats`), but with the
few runs of RL studies a percentile-bootstrap interval of a rank statistic is too narrow: at five
runs a side, verdicts read off whether it excludes 0.5 came out "larger" or "smaller" for 24 of
the 252 equally likely rankings of two alike methods (9.5 %, not 5 %). The verdict is therefore
a test with its stated level. Under "X and Y alike", every labelling of a task's pooled runs as
X or Y is as likely as the observed one, independently across tasks (the runs are permuted
within each task, never across). The statistic is the observed one, P(X > Y) averaged over the
tasks (each task's Mann-Whitney U / (n m), ties counting a half), and the p-value is the share
of labellings at least as far from 0.5 as the observed: exactly, over every labelling, where
there are at most :data:`EXACT_LABELLINGS`; else from :data:`PERMUTATIONS` random ones (a
Monte-Carlo p-value ``(1 + k) / (1 + B)``, whose test keeps its level too), drawn from a seed
derived from the pooled runs of each task and drawn as the runs of each task's smaller side,
so that neither the order of the tasks nor which side is X changes it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from hashlib import blake2b
from itertools import combinations

import numpy as np
from scipy.stats import rankdata

from tacbench.sequential import NOT_DISTINGUISHABLE

LEVEL = 0.05
"""The two-sided level of every verdict (each comparison on its own)."""
TOO_FEW_RUNS = "too few runs"
"""The verdict where no ranking of these run counts reaches :data:`LEVEL` (:func:`decidable`)."""
CHOSEN_ON_THESE_RUNS = "not tested: chosen on these runs"
"""The verdict of TAC (best q) where its q was picked among several by these runs' returns: a
test of the picked q against q = 1 (or a baseline) at :data:`LEVEL` would decide far more often
than its level where no q differs (docs/report.md, "TAC (best q)")."""
EXACT_LABELLINGS = 100_000
"""Up to this many labellings in all (the product over tasks of C(n + m, n)), every one is
counted: ten runs a side on one task are 184,756, beyond it; five a side on two tasks are
63,504."""
PERMUTATIONS = 10_000
"""Random labellings beyond :data:`EXACT_LABELLINGS`, as AdaStop's default: the Monte-Carlo
standard deviation of a p-value near 0.05 is then about 0.002."""
_TOLERANCE = 1e-9  # labellings as far from 0.5 as the observed one, up to float rounding


def labellings(sizes: Sequence[tuple[int, int]]) -> int:
    """How many labellings the test permutes over: prod_t C(n_t + m_t, n_t)."""
    return math.prod(math.comb(n + m, n) for n, m in sizes)


def decidable(xs: Sequence[np.ndarray], ys: Sequence[np.ndarray]) -> bool:
    """Whether these run counts (``xs[t]`` against ``ys[t]`` on each task t) could give a
    verdict at all: the most extreme rankings, every run of one side above every run of the
    other on every task, have probability 2 / prod_t C(n_t + m_t, n_t) when both are alike, the
    smallest p-value the test can give. Three runs a side are too few (2 / 20), four are enough
    (2 / 70)."""
    return 2 / labellings([(len(x), len(y)) for x, y in zip(xs, ys, strict=True)]) <= LEVEL


def _task_improvements(
    x: np.ndarray, y: np.ndarray, rng: np.random.Generator | None
) -> tuple[float, np.ndarray]:
    """P(X > Y) on one task, and the same for every labelling of its pooled runs as ``len(x)``
    X runs and the rest Y runs (``rng`` None), or for :data:`PERMUTATIONS` random ones.

    A labelling is drawn as the runs of the smaller side (of X where both have as many), so
    that swapping X and Y draws the same partitions of the pooled runs, each with P(X > Y)
    replaced by 1 - P(X > Y): the p-value does not depend on which side is X."""
    n, m = len(x), len(y)
    ranks = rankdata(np.concatenate([x, y]))  # midranks: a tie counts a half in U
    k = min(n, m)
    if rng is None:
        chosen = np.array(list(combinations(range(n + m), k)), dtype=np.intp).reshape(-1, k)
    else:
        chosen = rng.permuted(np.tile(np.arange(n + m), (PERMUTATIONS, 1)), axis=1)[:, :k]
    pooled = np.sort(ranks)  # labellings of the pooled runs, whichever side they came from
    offset, pairs = k * (k + 1) / 2, n * m
    chosen_above = (pooled[chosen].sum(axis=1) - offset) / pairs  # P(chosen > the others)
    null = chosen_above if k == n else 1 - chosen_above
    return (ranks[:n].sum() - n * (n + 1) / 2) / pairs, null


def _pooled(x: np.ndarray, y: np.ndarray) -> bytes:
    return np.sort(np.concatenate([x, y])).tobytes()


def _seed(xs: Sequence[np.ndarray], ys: Sequence[np.ndarray], seed: int) -> int:
    """A seed from ``seed`` and each task's pooled runs, the same whichever side is X and in
    whatever order the tasks come."""
    digest = blake2b(str(seed).encode(), digest_size=8)
    for task in sorted(_pooled(x, y) for x, y in zip(xs, ys, strict=True)):
        digest.update(task)
    return int.from_bytes(digest.digest(), "little")


def null_improvements(
    xs: Sequence[np.ndarray], ys: Sequence[np.ndarray], seed: int
) -> tuple[float, np.ndarray, bool]:
    """The observed P(X > Y) averaged over tasks, the same for every labelling (or for
    :data:`PERMUTATIONS` random ones, beyond :data:`EXACT_LABELLINGS`), and whether those are
    every labelling."""
    exact = labellings([(len(x), len(y)) for x, y in zip(xs, ys, strict=True)]) <= EXACT_LABELLINGS
    rng = None if exact else np.random.default_rng(_seed(xs, ys, seed))
    observed, null = 0.0, np.zeros(1)
    # tasks in the order of their pooled runs: the random labellings do not follow their order
    for x, y in sorted(zip(xs, ys, strict=True), key=lambda task: _pooled(*task)):
        task_observed, task_null = _task_improvements(x, y, rng)
        observed += task_observed
        # every combination of the tasks' labellings (exact), or the i-th draw of each task
        null = (null[:, None] + task_null[None, :]).ravel() if exact else null + task_null
    return observed / len(xs), null / len(xs), exact


def p_values(observed: np.ndarray, null: np.ndarray, exact: bool) -> np.ndarray:
    """The two-sided p-value of each ``observed`` P(X > Y) against the labellings' ``null``:
    the share at least as far from 0.5 (exact), or ``(1 + k) / (1 + B)``."""
    distances = np.sort(np.abs(null - 0.5))
    below = np.searchsorted(distances, np.abs(np.asarray(observed) - 0.5) - _TOLERANCE)
    extreme = len(distances) - below
    return extreme / len(distances) if exact else (1 + extreme) / (1 + len(distances))


def improvement_test(
    xs: Sequence[np.ndarray], ys: Sequence[np.ndarray], seed: int
) -> tuple[float, float]:
    """P(X > Y) averaged over tasks (``xs[t]`` against ``ys[t]`` on task t) and the two-sided
    p-value of the module's test of it under "X and Y alike"; ``seed`` as the report's
    intervals'."""
    xs = [np.sort(np.asarray(x, dtype=np.float64)) for x in xs]
    ys = [np.sort(np.asarray(y, dtype=np.float64)) for y in ys]
    if len(xs) != len(ys) or not xs or any(len(s) == 0 for s in (*xs, *ys)):
        raise ValueError("X and Y need runs on the same tasks, at least one each")
    if not all(np.isfinite(s).all() for s in (*xs, *ys)):
        raise ValueError("a test of P(X > Y) needs finite scores")
    observed, null, exact = null_improvements(xs, ys, seed)
    return observed, float(p_values(np.array([observed]), null, exact)[0])


def improvement_verdict(
    xs: Sequence[np.ndarray], ys: Sequence[np.ndarray], seed: int
) -> tuple[float, str]:
    """The p-value of :func:`improvement_test` and its verdict: ``larger`` or ``smaller``
    (the side of 0.5 the observed P(X > Y) lies on) where it is at most :data:`LEVEL`,
    :data:`TOO_FEW_RUNS` where these run counts cannot get there (:func:`decidable`), else
    :data:`~tacbench.sequential.NOT_DISTINGUISHABLE`."""
    observed, p_value = improvement_test(xs, ys, seed)
    if not decidable(xs, ys):
        return p_value, TOO_FEW_RUNS
    if p_value > LEVEL:
        return p_value, NOT_DISTINGUISHABLE
    return p_value, "larger" if observed > 0.5 else "smaller"
