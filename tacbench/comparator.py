"""adastop's comparator as :mod:`tacbench.sequential` runs it: its two-sided test fixed
(:func:`comparator_class`), and the keys of its dictionaries printed once (:func:`pairs_array`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import cache

import numpy as np

TIE_TOLERANCE = 1e-9
"""Relative difference below which a permuted statistic ties with the observed one."""


def comparator_class() -> type:
    """adastop's ``MultipleAgentsComparator`` with its two-sided test's null distribution
    fixed.

    adastop 0.1.3 (and its repository's head, da3a9d4) compares the statistic
    ``|mean difference|`` with quantiles of the permutation distribution of the *signed*
    difference (``max_mean_diffs`` in ``partial_compare``), so with equal group sizes, whose
    permutation distribution is symmetric, every comparison is tested at level 2 alpha: with
    n = 3, K = 1 and alpha = 0.1 it rejects when the observed labelling is one of the 2 largest
    of 20 in absolute value, 4 labellings of 20 (0.2), and on synthetic equal distributions the
    measured family-wise error is about 2 alpha (tests/test_sequential.py). The fix is the
    paper's statistic: the comparator takes the maximum of the *absolute* permuted
    differences. It keeps the signed sums it accumulates across interims and returns their
    absolute values to ``partial_compare``, which is all that reads them there.

    Those values are raised by a relative :data:`TIE_TOLERANCE`: ``partial_compare`` rejects
    where the observed statistic is strictly above the boundary, but computes it from means and
    the permuted values from blockwise sums, so the observed labelling's own value could fall a
    rounding error below it and a tie read as a rejection (docs/sequential.md).

    From the second interim on, where the first interim's labellings outnumber ``B`` (from
    n = 8 runs a side: C(16, 8) = 12,870 > 10,000), the package pairs each of the first
    interim's ``B`` random labellings with one of the new runs, but counts them as
    C(2n, n) ** 0 = 1: its boundary became the largest permuted value, which the observed
    labelling's own value cannot pass, and no comparison could be decided after the first
    interim. The count is ``B``, as at the first interim.
    """
    from adastop import MultipleAgentsComparator

    class TwoSidedComparator(MultipleAgentsComparator):
        def compute_mean_diffs(self, k: int, Z: list[np.ndarray]) -> dict[str, np.ndarray]:
            signed = super().compute_mean_diffs(k, Z)
            pair = self.current_comparisons[0]
            if k > 0 and math.comb(self.n[pair[0]] + self.n[pair[1]], self.n[pair[0]]) > self.B:
                self.normalization = self.B
            return {
                key: np.abs(np.asarray(values)) * (1 + TIE_TOLERANCE)
                for key, values in signed.items()
            }

    return TwoSidedComparator


class _Pairs(np.ndarray):
    """Comparisons (rows of two method indices) that print as NumPy prints them, from a cache.

    adastop keys its dictionaries by ``str(pair)`` and prints each pair again for every
    permutation of every interim (B x comparisons times; NumPy takes about 70 us a print): three
    quarters of the time of a decision with n = 15 and four methods. A row of this array prints
    its NumPy text, computed once per pair; nothing else about the array changes."""

    def __str__(self) -> str:
        return _printed(self.shape, tuple(self.ravel().tolist()))


@cache
def _printed(shape: tuple[int, ...], values: tuple[int, ...]) -> str:
    return str(np.array(values).reshape(shape))


def pairs_array(pairs: Sequence[tuple[int, int]]) -> np.ndarray:
    """The comparator's ``comparisons`` argument: the pairs of method indices, whose rows
    print as NumPy's own from a cache (:class:`_Pairs`)."""
    return np.array(pairs).view(_Pairs)
