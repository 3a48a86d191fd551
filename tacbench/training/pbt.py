"""``--q auto``: population-based training of the entropic index inside one process.

The paper picks q per task by a grid search and names learning "a proper entropic index for a
given task" as future work (its conclusion). Here the members of one run (at least
:data:`tacbench.members.MIN_POPULATION`; ``--seed`` repeated) form a population, trained with
the exploit/explore rule of Jaderberg et al. 2017 ("Population Based Training of Neural Networks"):

* **when**: every ``--pbt-every`` steps after ``--learning-starts`` (a round at step
  ``learning_starts + i * pbt_every``, i >= 1), all members at once;
* **ranking**: by each member's *score*, the mean return of its last :data:`RETURN_WINDOW`
  training episodes (never the evaluation, which must not influence learning); a member
  without a finished episode since it last changed ranks last; ties keep the member order
  (the order of ``--seed``); failed members take no part;
* **exploit**: each member of the bottom quarter (``n // 4`` of the n live members; none with
  fewer than four) copies a member of the top quarter, drawn uniformly: its networks, target
  networks, Adam moments and step counts and, with ``--alpha auto``, its log alpha (all of the
  learner's parameters, :meth:`tacbench.tac.TacAgent.copy_member`). It keeps its own replay
  buffer, environment and random streams, and its score starts afresh;
* **explore**: the copy's q is the source's times 0.8 or 1.2, drawn with equal chances
  (Jaderberg et al.'s "perturb" factors), clipped to ``--q-range``.

The members start at q spread evenly in log q over ``--q-range``
(:func:`tacbench.members.initial_qs`, in the order of ``--seed``). The draws come from one
generator per population, seeded by all the members' seeds (:func:`population_seed`), and its
state is part of every checkpoint, so a resumed population makes the same decisions. Every
member's ``pbt.csv`` has one row per round (:data:`PBT_COLUMNS`): its score and rank, whether
it copied and from whom, and its q before and after.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tacbench.errors import TacbenchError, listing
from tacbench.runs import read_json, read_status
from tacbench.runs.planning import resumable

if TYPE_CHECKING:
    from tacbench.config import RunConfig

RETURN_WINDOW = 10
PERTURB_FACTORS = (0.8, 1.2)  # Jaderberg et al. 2017, section 4 ("perturb")
PBT_COLUMNS = (
    "step",
    "seed",
    "score",
    "episodes",
    "rank",
    "copied_from",
    "source_score",
    "q_before",
    "q_after",
)
_STREAM = 18  # the PBT generator's spawn key, apart from run_streams' (fixed: seeds reproduce)


def population_seed(seeds: Sequence[int]) -> np.random.SeedSequence:
    """The seed of a population's generator: all its members' seeds, in order."""
    return np.random.SeedSequence([int(s) for s in seeds], spawn_key=(_STREAM,))


def check_whole_on_resume(directory: Path, seeds: Sequence[int], step: int) -> list[str]:
    """Before a population resumes from ``step`` with the members ``seeds`` (``directory`` is
    one's run): the members config.json records that the command leaves out. Every round ranks
    all live members, so one left out that was live at ``step`` would change every later round:
    a TacbenchError names it (a stopped or crashed member, or one whose run is gone; nothing is
    changed). One that failed by its own numbers after ``step`` cannot rejoin (its run is over),
    so the rounds it took part in after ``step`` can decide otherwise: a note says so. One that
    failed by ``step`` was out of every later round anyway."""
    recorded = read_json(directory / "config.json").get("members") or []
    # an older config.json lists the members' seeds alone
    recorded_seeds = [int(m["seed"] if isinstance(m, dict) else m) for m in recorded]
    notes, live, gone = [], [], []
    for seed in (s for s in recorded_seeds if s not in seeds):
        member = directory.parent / f"seed{seed}"
        if not (member / "config.json").exists():
            gone.append(str(member))
            continue
        status = read_status(member)
        if status.get("state") != "failed" or resumable(status):
            live.append(f"--seed {seed}")
        elif status["step"] > step:
            notes.append(
                f"seed {seed} failed at step {status['step']:,}, after step {step:,}, and cannot "
                f"rejoin: the rounds up to step {status['step']:,} rank the population without "
                "it, so they can decide otherwise than in the uninterrupted run"
            )
    if gone:
        raise TacbenchError(
            f"a --q auto population resumes as a whole, and the run of its member "
            f"{listing(gone)} is gone (no config.json). Nothing was changed; restore it, or "
            "start the population over with --force."
        )
    if live:
        raise TacbenchError(
            f"a --q auto population resumes as a whole: this command leaves out "
            f"{listing(live)}, live at step {step:,} in {directory.parent}, and every round "
            "ranks all live members. Nothing was changed; add them to the command."
        )
    return notes


@dataclass(frozen=True)
class Decision:
    """What one round decided for one member (indices into the population)."""

    member: int
    score: float  # NaN: no finished episode since the member last changed
    episodes: int
    rank: int  # 1 is the best
    source: int | None  # the member it copied, or None
    source_score: float  # NaN without a source
    q_before: float
    q_after: float


def decide(
    scores: Sequence[float],
    episodes: Sequence[int],
    qs: Sequence[float],
    alive: Sequence[bool],
    q_range: Sequence[float],
    rng: np.random.Generator,
) -> list[Decision]:
    """One exploit/explore round over the live members, as the module docstring says."""
    live = [k for k in range(len(qs)) if alive[k]]
    order = sorted(live, key=lambda k: (-scores[k] if not math.isnan(scores[k]) else math.inf, k))
    quarter = len(live) // 4
    top, bottom = order[:quarter], set(order[len(order) - quarter :]) if quarter else set()
    decisions = []
    for rank, k in enumerate(order, start=1):
        source, source_score, q_after = None, math.nan, qs[k]
        if k in bottom:
            source = top[int(rng.integers(len(top)))]
            source_score = scores[source]
            factor = PERTURB_FACTORS[int(rng.integers(len(PERTURB_FACTORS)))]
            q_after = min(max(qs[source] * factor, q_range[0]), q_range[1])
        decisions.append(
            Decision(k, scores[k], episodes[k], rank, source, source_score, qs[k], q_after)
        )
    return sorted(decisions, key=lambda d: d.member)


class Population:
    """The PBT state of a group: each member's q and recent training returns, the generator."""

    def __init__(self, seeds: Sequence[int], qs: Sequence[float], config: RunConfig):
        self.seeds = list(seeds)
        self.qs = [float(q) for q in qs]
        self.every, self.start = config.pbt_every, config.learning_starts
        self.end = config.total_steps
        self.returns: list[deque[float]] = [deque(maxlen=RETURN_WINDOW) for _ in seeds]
        self.rng = np.random.default_rng(population_seed(seeds))

    def due(self, step: int) -> bool:
        """Whether a round happens after ``step`` (never after the last)."""
        return self.start < step < self.end and (step - self.start) % self.every == 0

    def episode_ended(self, member: int, episode_return: float) -> None:
        """Record a finished training episode of ``member``."""
        self.returns[member].append(float(episode_return))

    def scores(self) -> list[float]:
        """Each member's mean recent training return (NaN without one)."""
        return [float(np.mean(r)) if r else math.nan for r in self.returns]

    def round(self, alive: Sequence[bool], q_range: Sequence[float]) -> list[Decision]:
        """Decide a round and apply it to q and the scores (the caller copies the learners)."""
        counts = [len(r) for r in self.returns]
        decisions = decide(self.scores(), counts, self.qs, alive, q_range, self.rng)
        for d in decisions:
            if d.source is not None:
                self.qs[d.member] = d.q_after
                self.returns[d.member].clear()
        return decisions

    def row(self, step: int, d: Decision) -> list[Any]:
        """``d`` as a row of :data:`PBT_COLUMNS`."""
        source = "" if d.source is None else self.seeds[d.source]
        source_score = "" if d.source is None else d.source_score
        return [
            step,
            self.seeds[d.member],
            d.score,
            d.episodes,
            d.rank,
            source,
            source_score,
            d.q_before,
            d.q_after,
        ]

    def moves(self, decisions: Sequence[Decision]) -> str:
        """The copies among ``decisions``, as ``copier<-source q=new`` by seed ("" for none)."""
        return ", ".join(
            f"{self.seeds[d.member]}<-{self.seeds[d.source]} q={d.q_after:.3g}"
            for d in decisions
            if d.source is not None
        )

    def member_state(self, k: int) -> dict[str, Any]:
        """Member k's part of a checkpoint (the generator's state is the population's)."""
        state = self.rng.bit_generator.state
        return {"q": self.qs[k], "returns": list(self.returns[k]), "rng": state}

    def load_member_states(self, states: Sequence[dict[str, Any]]) -> None:
        """Restore every member's :meth:`member_state` (the generator from the first)."""
        for k, state in enumerate(states):
            self.qs[k] = float(state["q"])
            self.returns[k].clear()
            self.returns[k].extend(state["returns"])
        self.rng.bit_generator.state = states[0]["rng"]
