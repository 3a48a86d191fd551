"""The verdict on P(X > Y): a stratified permutation test of the probability of improvement.

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
derived from the scores as the intervals' are.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from itertools import combinations

import numpy as np
from scipy.stats import rankdata

from tacbench.bootstrap import strata_seed
from tacbench.sequential import NOT_DISTINGUISHABLE

LEVEL = 0.05
"""The two-sided level of every verdict (each comparison on its own)."""
TOO_FEW_RUNS = "too few runs"
"""The verdict where no ranking of these run counts reaches :data:`LEVEL` (:func:`decidable`)."""
EXACT_LABELLINGS = 100_000
"""Up to this many labellings in all (the product over tasks of C(n + m, n)), every one is
counted: ten runs a side on one task are 184,756, beyond it; five a side on two tasks are
63,504."""
PERMUTATIONS = 10_000
"""Random labellings beyond :data:`EXACT_LABELLINGS`, as AdaStop's default: the Monte-Carlo
standard deviation of a p-value near 0.05 is then about 0.002."""
_TOLERANCE = 1e-9  # labellings as far from 0.5 as the observed one, up to float rounding


def decidable(xs: Sequence[np.ndarray], ys: Sequence[np.ndarray]) -> bool:
    """Whether these run counts (``xs[t]`` against ``ys[t]`` on each task t) could give a
    verdict at all: the most extreme rankings, every run of one side above every run of the
    other on every task, have probability 2 / prod_t C(n_t + m_t, n_t) when both are alike, the
    smallest p-value the test can give. Three runs a side are too few (2 / 20), four are enough
    (2 / 70)."""
    labellings = math.prod(math.comb(len(x) + len(y), len(x)) for x, y in zip(xs, ys, strict=True))
    return 2 / labellings <= LEVEL


def _improvement_of_labellings(
    x: np.ndarray, y: np.ndarray, rng: np.random.Generator | None
) -> tuple[float, np.ndarray]:
    """P(X > Y) on one task, and the same for every labelling of its pooled runs as ``len(x)``
    X runs and the rest Y runs (``rng`` None), or for :data:`PERMUTATIONS` random ones."""
    n, m = len(x), len(y)
    ranks = rankdata(np.concatenate([x, y]))  # midranks: a tie counts a half in U
    if rng is None:
        chosen = np.array(list(combinations(range(n + m), n)), dtype=np.intp).reshape(-1, n)
    else:
        chosen = rng.permuted(np.tile(np.arange(n + m), (PERMUTATIONS, 1)), axis=1)[:, :n]
    offset, pairs = n * (n + 1) / 2, n * m
    return (ranks[:n].sum() - offset) / pairs, (ranks[chosen].sum(axis=1) - offset) / pairs


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
    labellings = math.prod(math.comb(len(x) + len(y), len(x)) for x, y in zip(xs, ys, strict=True))
    exact = labellings <= EXACT_LABELLINGS
    rng = None if exact else np.random.default_rng(strata_seed(seed, [*xs, *ys]))
    observed, null = 0.0, np.zeros(1)
    for x, y in zip(xs, ys, strict=True):
        task_observed, task_null = _improvement_of_labellings(x, y, rng)
        observed += task_observed
        # every combination of the tasks' labellings (exact), or the i-th draw of each task
        null = (null[:, None] + task_null[None, :]).ravel() if exact else null + task_null
    observed, null = observed / len(xs), null / len(xs)
    extreme = int((np.abs(null - 0.5) >= abs(observed - 0.5) - _TOLERANCE).sum())
    return observed, extreme / len(null) if exact else (1 + extreme) / (1 + PERMUTATIONS)


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
