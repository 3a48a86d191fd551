"""Sequential comparisons (tacbench/sequential.py): AdaStop's procedure keeps the family-wise
error rate at alpha on equal synthetic distributions (once its two-sided test is fixed), finds
large true differences, replays the committed paper-q-grid study deterministically, and the
detectable difference has the power it states."""

from __future__ import annotations

import itertools
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from tacbench import comparator
from tacbench import sequential as sq
from tacbench.cli import cli
from tacbench.errors import TacbenchError
from tests.report_fixtures import write_run

pytestmark = pytest.mark.unit

STUDY = Path(__file__).resolve().parents[1] / "results" / "studies" / "paper-q-grid-100k"


def _null_rejections(comparator: type, repeats: int, alpha: float) -> float:
    """The share of ``repeats`` synthetic grids of three equal normal methods (4 runs each,
    two interims of two) in which any comparison with the control is rejected."""
    rng = np.random.default_rng(1)
    rejected = 0
    for repeat in range(repeats):
        scores = {m: rng.normal(0.0, 1.0, 4) for m in (0, 1, 2)}
        c = comparator(n=2, K=2, B=10_000, comparisons=np.array([(1, 0), (2, 0)]), alpha=alpha)
        c.rng = np.random.RandomState(repeat)
        for k in (1, 2):
            c.partial_compare({m: v[: 2 * k] for m, v in scores.items()}, verbose=False)
        rejected += any(d in ("larger", "smaller") for d in c.decisions.values())
    return rejected / repeats


def test_the_fixed_comparator_keeps_the_family_wise_error_rate() -> None:
    from adastop import MultipleAgentsComparator

    alpha, repeats = 0.1, 200
    mc_error = 3 * math.sqrt(alpha * (1 - alpha) / repeats)  # three standard errors
    assert _null_rejections(comparator.comparator_class(), repeats, alpha) <= alpha + mc_error
    # the package's own comparator tests each comparison at about twice the level
    assert _null_rejections(MultipleAgentsComparator, repeats, alpha) > alpha + mc_error


def test_over_every_labelling_the_fixed_test_rejects_alpha_of_them() -> None:
    from adastop import MultipleAgentsComparator

    values = np.array([0.3, 1.1, 2.7, 3.2, 4.9, 6.4])

    def rejected(comparator: type) -> int:
        count = 0
        for chosen in itertools.combinations(range(6), 3):
            c = comparator(n=3, K=1, comparisons=np.array([(0, 1)]), alpha=0.1, seed=0)
            scores = {"a": values[list(chosen)], "b": np.delete(values, list(chosen))}
            c.partial_compare(scores, verbose=False)
            count += c.decisions["[0 1]"] != "equal"
        return count

    assert rejected(comparator.comparator_class()) == 2  # 2 of 20 labellings: alpha = 0.1
    assert rejected(MultipleAgentsComparator) == 4  # the package's: 2 alpha


def test_a_large_true_difference_is_found_and_its_sign_is_right() -> None:
    rng = np.random.default_rng(2)
    found = 0
    for repeat in range(40):
        scores = {"a": rng.normal(0.0, 1.0, 6), "b": rng.normal(3.0, 1.0, 6)}
        result = sq.run_sequential(scores, n=3, K=2, alpha=0.05, control="a", seed=repeat)
        found += result.decisions[("b", "a")] == "larger"
    assert found >= 36  # a fixed test of 6 runs each has power above 0.99 at 3 standard deviations


def test_an_early_decision_stops_spending_runs() -> None:
    # 4 runs each per interim: 70 labellings, so the first interim can reach alpha / K
    scores = {"a": [0.0, 0.1, 0.2, 0.3] * 2, "b": [9.0, 9.1, 9.2, 9.3] * 2}
    result = sq.run_sequential(scores, n=4, K=2, alpha=0.1, control="a")
    assert result.decided_at(("b", "a")) == 1
    assert result.runs_spent == 8 and result.fixed_runs == 16
    assert len(result.interims) == 1


def test_a_difference_from_the_second_interim_is_decided_where_labellings_outnumber_b() -> None:
    """With more labellings of an interim's runs than B (C(10, 5) = 252 > 200 here; at the
    default B = 10,000 from n = 8), the package counted the second interim's B paired
    labellings as 1, and nothing could be decided after the first interim."""
    rng = np.random.default_rng(3)
    first = rng.normal(0.0, 1.0, 10)
    scores = {"a": np.r_[first[:5], rng.normal(0.0, 1.0, 10)], "b": np.r_[first[5:], 20 + first]}
    result = sq.run_sequential(scores, n=5, K=3, alpha=0.05, control="a", B=200)
    assert result.decisions[("b", "a")] == "larger" and result.decided_at(("b", "a")) == 2


def test_with_labellings_sampled_the_later_interims_keep_the_error_rate() -> None:
    alpha, repeats = 0.1, 200
    rng = np.random.default_rng(4)
    rejected = 0
    for repeat in range(repeats):
        scores = {m: rng.normal(0.0, 1.0, 15) for m in ("a", "b")}
        result = sq.run_sequential(scores, n=5, K=3, alpha=alpha, control="a", B=200, seed=repeat)
        rejected += result.decisions[("b", "a")] in ("larger", "smaller")
    assert rejected / repeats <= alpha + 3 * math.sqrt(alpha * (1 - alpha) / repeats)


def test_the_replay_of_the_committed_study_is_deterministic_and_honest() -> None:
    first = sq.decision_table(sq.replay_study(STUDY, n=5, K=1))
    again = sq.decision_table(sq.replay_study(STUDY, n=5, K=1))
    assert first.equals(again)
    names = first["env"] + " " + first["method"] + " vs " + first["against"]
    verdicts = dict(zip(names, first["decision"], strict=True))
    assert verdicts["HalfCheetah-v4 q=2 vs q=1"] == "smaller"  # the failure is decided
    assert verdicts["HalfCheetah-v4 q=1.5 vs q=1"] == sq.NOT_DISTINGUISHABLE
    four = sq.decision_table(sq.replay_study(STUDY, n=4, K=1))  # the first four seeds decide
    assert four["decision"].tolist() == first["decision"].tolist()
    assert four["runs"].sum() == first["runs"].sum() * 4 // 5
    # one run per method per interim cannot reach alpha = 0.05 two-sided (2 / 2^5 > 0.05)
    sequential = sq.decision_table(sq.replay_study(STUDY, n=1, K=5))
    assert set(sequential["decision"]) == {sq.NOT_DISTINGUISHABLE}


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"n": 0, "K": 2}, "n and K must be at least 1"),
        ({"n": 2, "K": 2, "alpha": 1.5}, "alpha must lie in"),
        ({"n": 2, "K": 2, "control": "c"}, "the control 'c' is not one of"),
        ({"n": 3, "K": 2}, "fewer than n x K = 6 scores"),
    ],
)
def test_a_design_it_cannot_run_is_refused(kwargs: dict, message: str) -> None:
    with pytest.raises(TacbenchError, match=message):
        sq.run_sequential({"a": [1.0] * 4, "b": [2.0] * 4}, **kwargs)
    with pytest.raises(TacbenchError, match="at least two methods"):
        sq.run_sequential({"a": [1.0] * 4}, n=2, K=2)


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_a_score_that_is_not_finite_is_refused(bad: float) -> None:
    """One NaN used to turn every comparison of the family into "not distinguishable"."""
    scores = {"a": [1.0, 2, 3, 4, 5], "b": [10.0, 11, bad, 13, 14], "c": [20.0, 21, 22, 23, 24]}
    with pytest.raises(TacbenchError, match="the scores of b are not all finite"):
        sq.run_sequential(scores, 5, 1, control="a")


def test_a_replay_of_a_study_short_of_runs_names_the_task_and_the_q(tmp_path: Path) -> None:
    for q, seeds in ((1.0, range(0, 50, 10)), (2.0, range(0, 40, 10))):
        for seed in seeds:
            write_run(
                tmp_path,
                algo="tac",
                env="Hopper-v4",
                variant=f"q{q:g}-a0.2",
                seed=seed,
                steps=[1.0, 2.0],
                returns=[1.0, float(seed)],
                q=q,
                alpha=0.2,
            )
    with pytest.raises(TacbenchError, match="Hopper-v4: q=2 has fewer than the 5 complete runs"):
        sq.replay_study(tmp_path, 5, 1)
    # a fifth run that the loader left out is named with its reason (the message hid it)
    broken = write_run(
        tmp_path,
        algo="tac",
        env="Hopper-v4",
        variant="q2-a0.2",
        seed=40,
        steps=[1.0],
        returns=[1.0],
    )
    (broken / "config.json").write_text("")
    with pytest.raises(TacbenchError) as short:
        sq.replay_study(tmp_path, 5, 1)
    assert "(left out: tac/Hopper-v4/q2-a0.2/seed40: config.json unreadable" in str(short.value)


def _write_tac_runs(root: Path, variant: str, q: float, **modes: str) -> None:
    """Five complete Hopper runs of ``variant`` (``modes``: q_mode, alpha_mode)."""
    for seed in range(0, 50, 10):
        settings = {"algo": "tac", "env": "Hopper-v4", "seed": seed, **modes}
        run = write_run(
            root,
            algo="tac",
            env="Hopper-v4",
            variant=variant,
            seed=seed,
            steps=[1.0, 2.0],
            returns=[1.0, float(seed)],
            q=q,
            alpha=0.2,
            settings=settings,
        )
        if modes.get("q_mode") == "auto":  # a population member names its population
            config = json.loads((run / "config.json").read_text())
            config["members"] = [{"seed": seed}]
            (run / "config.json").write_text(json.dumps(config))


@pytest.mark.parametrize(
    ("variants", "message"),
    [
        (
            [("q1-a0.2", 1.0, {}), ("q1-aauto0.2", 1.0, {"alpha_mode": "auto"})],
            "Hopper-v4: q=1 has q1-a0.2, q1-aauto0.2. The replay compares one setting per q",
        ),
        (
            [("q1-a0.2", 1.0, {}), ("qauto-a0.2", 0.5, {"q_mode": "auto"})],
            "Hopper-v4: qauto-a0.2 has no fixed q.",
        ),
    ],
)
def test_a_replay_refuses_runs_it_would_take_for_one_q(
    tmp_path: Path, variants: list[tuple[str, float, dict[str, str]]], message: str
) -> None:
    """Two settings of one q (fixed and learned alpha) used to be replayed as one method, seed 0
    counted twice; runs of a learned q were left out without a word."""
    for variant, q, modes in variants:
        _write_tac_runs(tmp_path, variant, q, **modes)
    with pytest.raises(TacbenchError, match=re.escape(message)):
        sq.replay_study(tmp_path, 5, 1)


def test_a_replay_of_a_folder_without_tac_runs_is_refused(tmp_path: Path) -> None:
    write_run(tmp_path, algo="sac", env="Hopper-v4", variant="sb3", seed=0, steps=[1], returns=[1])
    with pytest.raises(TacbenchError, match="no complete TAC run under"):
        sq.replay_study(tmp_path, 5, 1)


def test_analyse_checks_out_before_its_minutes_of_work(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("")
    args = ["study", "sequential", "analyse", "--results", str(STUDY), "--reps", "1"]
    result = CliRunner().invoke(cli, [*args, "--out", str(tmp_path / "file" / "sub")])
    assert result.exit_code == 2 and "cannot create or write the output folder" in result.output
    assert "replay:" not in result.output  # nothing was analysed


def test_the_pairs_print_as_numpys_and_decide_as_a_plain_array() -> None:
    """adastop keys its dictionaries by ``str(pair)``: the cached print must be NumPy's own,
    padding included, and the decisions those of the package given a plain array."""
    pairs = comparator.pairs_array([(0, 1), (2, 10), (11, 3)])
    for plain, printed in zip(np.array([(0, 1), (2, 10), (11, 3)]), pairs, strict=True):
        assert str(printed) == str(plain)
    assert str(pairs[0]) == "[0 1]" and str(pairs[1]) == "[ 2 10]"

    rng = np.random.default_rng(3)
    scores = {m: rng.normal(shift, 1.0, 10) for m, shift in (("a", 0.0), ("b", 2.0), ("c", 0.1))}
    decided = []
    for comparisons in (np.array([(0, 1), (0, 2)]), comparator.pairs_array([(0, 1), (0, 2)])):
        c = comparator.comparator_class()(n=5, K=2, B=2000, comparisons=comparisons, seed=0)
        for k in (1, 2):
            c.partial_compare({m: v[: 5 * k] for m, v in scores.items()}, verbose=False)
        decided.append(dict(c.decisions))
    assert decided[0] == decided[1] and decided[0]["[0 1]"] == "smaller"
