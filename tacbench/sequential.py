"""Verdicts with the fewest runs: group-sequential comparisons with AdaStop
(docs/sequential.md).

AdaStop (Mathieu et al., arXiv 2306.10882; the ``adastop`` package) compares methods from
their runs' scores in interims: each interim adds ``n`` runs of every method still in an
undecided comparison, and a permutation test with a group-sequential boundary decides each
comparison (``larger``, ``smaller``) or lets it continue, at most ``K`` interims, keeping the
family-wise error rate of all the task's comparisons at ``alpha``. A comparison still open
after the last interim is what the package calls ``equal``; here it reads "not
distinguishable", since AdaStop (with its default ``beta = 0``) never accepts equality early.

:func:`run_sequential` feeds a method's scores in seed order (the order a sweep would train
them) and records each interim; :func:`replay_study` does that for a committed study, to say
how many runs each verdict needed against the fixed design it ran. What a verdict left open
could have detected: :mod:`tacbench.detectable`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from tacbench import comparator
from tacbench.errors import TacbenchError, listing

DEFAULT_ALPHA = 0.05  # the usual 5% family-wise error rate; AdaStop's own default is 0.01
DEFAULT_B = 10_000  # AdaStop's default number of random permutations
NOT_DISTINGUISHABLE = "not distinguishable"
DECIDED = ("larger", "smaller")
Pair = tuple[str, str]


@dataclass(frozen=True)
class Interim:
    """What the comparator decided after one interim: the runs each method had given by then
    and each comparison's state (``larger``/``smaller``: the first method's mean against the
    second's; ``continue``; after the last interim, undecided ones are
    :data:`NOT_DISTINGUISHABLE`)."""

    number: int  # 1-based
    runs: dict[str, int]
    decisions: dict[Pair, str]


@dataclass(frozen=True)
class SequentialResult:
    """Every interim of one task's comparisons, with what they cost."""

    methods: tuple[str, ...]
    comparisons: tuple[Pair, ...]
    n: int
    K: int
    alpha: float
    interims: tuple[Interim, ...]

    @property
    def decisions(self) -> dict[Pair, str]:
        """Each comparison's final verdict."""
        return self.interims[-1].decisions

    def decided_at(self, pair: Pair) -> int | None:
        """The interim at which ``pair`` was decided (None: not distinguishable)."""
        for interim in self.interims:
            if interim.decisions[pair] in DECIDED:
                return interim.number
        return None

    @property
    def runs_spent(self) -> int:
        """Runs the procedure trained, over every method."""
        return sum(self.interims[-1].runs.values())

    @property
    def fixed_runs(self) -> int:
        """Runs of the fixed design of ``n x K`` seeds per method."""
        return self.n * self.K * len(self.methods)


def check_design(n: int, K: int, alpha: float, methods: Sequence[str], control: str | None) -> None:
    """Refuse (TacbenchError) what AdaStop cannot run: n or K below 1, alpha outside (0, 1),
    one method, or a control that is not among the methods."""
    if n < 1 or K < 1:
        raise TacbenchError(f"n and K must be at least 1 (got n={n}, K={K}).")
    if not 0.0 < alpha < 1.0:
        raise TacbenchError(f"alpha must lie in (0, 1) (got {alpha!r}).")
    if len(methods) < 2:
        raise TacbenchError(f"a comparison needs at least two methods (got {list(methods)}).")
    if control is not None and control not in methods:
        raise TacbenchError(f"the control {control!r} is not one of the methods {list(methods)}.")


def comparisons_for(methods: Sequence[str], control: str | None) -> list[Pair]:
    """Each method against ``control``, or every pair (in the order of ``methods``)."""
    if control is not None:
        return [(m, control) for m in methods if m != control]
    return [(a, b) for i, a in enumerate(methods) for b in methods[i + 1 :]]


class SequentialComparison:
    """One task's comparisons, fed interim by interim (what ``tacbench sweep --until-decided``
    and :func:`run_sequential` do).

    Before each interim, :meth:`runs_needed` says how many runs each method must have given
    (``n`` more for every method still in an undecided comparison); :meth:`add` takes at least
    that many scores per method, in the order the runs were trained, and decides. The
    comparator is seeded by ``seed``, so adding the same scores again reaches the same
    decisions: a sweep rebuilds it from the scores it recorded.
    """

    def __init__(
        self,
        methods: Sequence[str],
        n: int,
        K: int,
        alpha: float = DEFAULT_ALPHA,
        control: str | None = None,
        B: int = DEFAULT_B,
        seed: int = 0,
    ) -> None:
        check_design(n, K, alpha, methods, control)
        self.methods = tuple(methods)
        self.n, self.K, self.alpha = n, K, alpha
        self.pairs = tuple(comparisons_for(methods, control))
        index = {m: i for i, m in enumerate(methods)}
        self._comparator = comparator.comparator_class()(
            n=n,
            K=K,
            B=B,
            comparisons=comparator.pairs_array([(index[a], index[b]) for a, b in self.pairs]),
            alpha=alpha,
            seed=seed,
        )
        self._keys = {str(np.array([index[a], index[b]])): (a, b) for a, b in self.pairs}
        self.interims: list[Interim] = []

    @property
    def finished(self) -> bool:
        """Every comparison decided, or the last interim done."""
        return len(self.interims) == self.K or (
            bool(self.interims) and bool(self._comparator.is_finished)
        )

    def open_pairs(self) -> list[Pair]:
        """The comparisons still undecided (all of them before the first interim)."""
        if not self.interims:
            return list(self.pairs)
        return [p for p, d in self.interims[-1].decisions.items() if d == "continue"]

    def runs_needed(self) -> dict[str, int]:
        """The runs each method must have given for the next interim: ``n`` more than before
        for a method in an undecided comparison, as many as before for the others."""
        if self.finished:
            raise TacbenchError("the comparisons are finished; no further interim is needed.")
        given = dict(self.interims[-1].runs) if self.interims else dict.fromkeys(self.methods, 0)
        k = len(self.interims) + 1
        for method in {m for pair in self.open_pairs() for m in pair}:
            given[method] = self.n * k
        return given

    def add(self, scores: Mapping[str, Sequence[float]]) -> Interim:
        """Decide the next interim from the first :meth:`runs_needed` scores of each method."""
        needed = self.runs_needed()
        short = [m for m in self.methods if len(scores.get(m, ())) < needed[m]]
        if short:
            raise TacbenchError(
                f"interim {len(self.interims) + 1} needs "
                + ", ".join(f"{needed[m]} scores of {m}" for m in short)
                + f" (got {', '.join(str(len(scores.get(m, ()))) for m in short)})."
            )
        values = {m: np.asarray(scores[m][: needed[m]], dtype=np.float64) for m in self.methods}
        unusable = [m for m, v in values.items() if not np.isfinite(v).all()]
        if unusable:  # one NaN made every comparison of the family "not distinguishable"
            raise TacbenchError(
                f"interim {len(self.interims) + 1}: the scores of {', '.join(unusable)} are not "
                "all finite numbers; leave a failed or diverged run out, or score it."
            )
        self._comparator.partial_compare(values, verbose=False)
        decisions = {self._keys[key]: state for key, state in self._comparator.decisions.items()}
        if len(self.interims) == self.K - 1:
            decisions = {
                p: NOT_DISTINGUISHABLE if d == "equal" else d for p, d in decisions.items()
            }
        interim = Interim(len(self.interims) + 1, needed, decisions)
        self.interims.append(interim)
        return interim

    def result(self) -> SequentialResult:
        """The interims so far, with what they cost."""
        return SequentialResult(
            self.methods, self.pairs, self.n, self.K, self.alpha, tuple(self.interims)
        )


def run_sequential(
    scores: Mapping[str, Sequence[float]],
    n: int,
    K: int,
    alpha: float = DEFAULT_ALPHA,
    control: str | None = None,
    B: int = DEFAULT_B,
    seed: int = 0,
) -> SequentialResult:
    """AdaStop's comparisons of the methods of ``scores`` (each method's scores in the order
    its runs would be trained; at least ``n x K`` each), interim by interim
    (:class:`SequentialComparison`). ``seed`` fixes the comparator's random permutations, so a
    replay reaches the same decisions."""
    comparison = SequentialComparison(list(scores), n, K, alpha, control, B, seed)
    short = [m for m in scores if len(scores[m]) < n * K]
    if short:
        raise TacbenchError(
            f"{', '.join(short)} {'has' if len(short) == 1 else 'have'} fewer than n x K = "
            f"{n * K} scores; lower n or K."
        )
    while not comparison.finished:
        comparison.add(scores)
    return comparison.result()


def study_scores(results: Path) -> tuple[pd.DataFrame, list[str]]:
    """One row per complete TAC run of a study folder: env, variant, q, seed and its final
    return (the report's: the mean of its last 10 evaluations), in seed order; and
    ``"<run>: <reason>"`` for each run directory the report's loader left out."""
    from tacbench.report.load import load_runs
    from tacbench.report.tables import DEFAULT_LAST, run_scores

    runset = load_runs(results, "eval")
    table = runset.runs.join(run_scores(runset.data, DEFAULT_LAST), on="run")
    table = table[(table["algo"] == "tac") & ~table["partial"]]
    left_out = [f"{s.path}: {s.reason}" for s in runset.skipped]
    columns = ["env", "variant", "q", "seed", "final"]
    return table[columns].sort_values(["env", "q", "seed"]), left_out


def replay_study(
    results: Path, n: int, K: int, alpha: float = DEFAULT_ALPHA, control_q: float = 1.0
) -> dict[str, SequentialResult]:
    """For each task of the study at ``results``: its runs replayed in seed order through
    :func:`run_sequential`, each q against ``control_q``. A TacbenchError where the folder
    holds no complete TAC run, or a task holds more than one setting of a q, or runs without a
    fixed q (q auto): their runs would be taken as one method's."""
    table, left_out = study_scores(results)
    if table.empty:
        raise TacbenchError(
            f"no complete TAC run under {results}: nothing to replay; give --results a q-grid "
            "study's folder (results/studies/paper-q-grid-100k, the default)."
        )
    replays = {}
    for env, runs in table.groupby("env", sort=True):
        _check_one_setting_per_q(str(env), runs)
        by_q = {f"q={q:g}": group["final"].tolist() for q, group in runs.groupby("q", sort=True)}
        short = sorted(q for q, scores in by_q.items() if len(scores) < n * K)
        if short:
            raise TacbenchError(
                f"{env}: {', '.join(short)} {'has' if len(short) == 1 else 'have'} fewer than "
                f"the {n * K} complete runs a replay of n = {n}, K = {K} needs; the replayed "
                "study needs every q's runs on every task"
                + (f" (left out: {listing(left_out, 3, '; ')})." if left_out else ".")
            )
        replays[str(env)] = run_sequential(by_q, n, K, alpha, control=f"q={control_q:g}")
    return replays


def _check_one_setting_per_q(env: str, runs: pd.DataFrame) -> None:
    """A TacbenchError naming the settings of ``env``'s runs that a replay by q cannot tell
    apart."""
    mixed = [
        f"q={q:g} has {', '.join(sorted(variants))}"
        for q, variants in runs.groupby("q", sort=True)["variant"].unique().items()
        if len(variants) > 1
    ]
    unfixed = sorted(runs.loc[runs["q"].isna(), "variant"].unique())
    if unfixed:
        mixed.append(f"{', '.join(unfixed)} {'has' if len(unfixed) == 1 else 'have'} no fixed q")
    if mixed:
        raise TacbenchError(
            f"{env}: {'; '.join(mixed)}. The replay compares one setting per q (as the "
            "paper-q-grid study has): give it a folder with the runs of one setting per q."
        )


def decision_table(results: Mapping[str, SequentialResult]) -> pd.DataFrame:
    """One row per task and comparison: ``env``, ``method``, ``against``, ``decision``, the
    ``interim`` it was decided at (None: not distinguishable) and the ``runs`` its two methods
    had given by then."""
    rows = []
    for env, result in results.items():
        last = result.interims[-1]
        for pair in result.comparisons:
            at = result.decided_at(pair)
            given = (result.interims[at - 1] if at else last).runs
            rows.append(
                {
                    "env": env,
                    "method": pair[0],
                    "against": pair[1],
                    "decision": result.decisions[pair],
                    "interim": at,
                    "runs": given[pair[0]] + given[pair[1]],
                }
            )
    columns = ["env", "method", "against", "decision", "interim", "runs"]
    return pd.DataFrame(rows, columns=columns)


def spending_table(results: Mapping[str, SequentialResult]) -> pd.DataFrame:
    """One row per task: interims done, runs spent, and the runs of the fixed ``n x K`` design."""
    rows = [
        {
            "env": env,
            "interims": len(result.interims),
            "runs": result.runs_spent,
            "fixed_design_runs": result.fixed_runs,
        }
        for env, result in results.items()
    ]
    return pd.DataFrame(rows, columns=["env", "interims", "runs", "fixed_design_runs"])


def decision_text(results: Mapping[str, SequentialResult]) -> str:
    """Each task's decisions and the runs they cost, against the fixed design, as lines."""
    lines = []
    for env, result in results.items():
        done = len(result.interims)
        lines.append(
            f"{env}: {done} interim{'s' if done > 1 else ''}, {result.runs_spent} runs (a fixed "
            f"design of {result.n} x {result.K} seeds: {result.fixed_runs})"
        )
        for row in decision_table({env: result}).to_dict("records"):
            decided = (
                f" (interim {row['interim']:g}, {row['runs']} runs)"
                if row["decision"] in DECIDED
                else ""
            )
            lines.append(f"  {row['method']} vs {row['against']}: {row['decision']}{decided}")
    return "\n".join(lines)
