"""``--q auto``: population-based training of q (tacbench/training/pbt.py). The selection, copy
and perturbation rules on toy populations (ties, dead members, small populations), an exact
copy of a member's learner, a resumed population equal to an uninterrupted one, and bad input
as usage errors."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import torch

from tacbench.cli import cli
from tacbench.config import RunConfig
from tacbench.errors import TacbenchError
from tacbench.members import initial_qs, make_run_configs
from tacbench.tac import TacAgent
from tacbench.training import loop
from tacbench.training.pbt import (
    PBT_COLUMNS,
    PERTURB_FACTORS,
    Population,
    check_whole_on_resume,
    decide,
    population_seed,
)
from tests.helpers import TINY_RUN, TINY_TAC, assert_same_results, train

RANGE = (0.5, 5.0)


def _decide(scores: list[float], alive: list[bool] | None = None, seed: int = 0) -> list:
    n = len(scores)
    qs = [1.0 + i for i in range(n)]
    return decide(scores, [10] * n, qs, alive or [True] * n, RANGE, np.random.default_rng(seed))


@pytest.mark.unit
def test_the_bottom_quarter_copies_the_top_quarter_and_perturbs_its_q() -> None:
    scores = [5.0, 1.0, 7.0, 3.0, 8.0, 2.0, 6.0, 4.0]  # ranks: 4 8 2 6 1 7 3 5
    decisions = _decide(scores)
    assert [d.rank for d in decisions] == [4, 8, 2, 6, 1, 7, 3, 5]
    copied = {d.member: d for d in decisions if d.source is not None}
    assert set(copied) == {1, 5}  # the two worst of eight
    for d in copied.values():
        assert d.source in (4, 2)  # the two best
        source_q = 1.0 + d.source
        assert any(d.q_after == pytest.approx(source_q * f) for f in PERTURB_FACTORS)
        assert d.q_before == 1.0 + d.member
        assert d.source_score == scores[d.source]
    kept = [d for d in decisions if d.source is None]
    assert all(d.q_after == d.q_before and math.isnan(d.source_score) for d in kept)


@pytest.mark.unit
def test_ties_keep_the_member_order_and_no_episode_ranks_last() -> None:
    decisions = _decide([2.0, 2.0, 2.0, math.nan, 2.0])
    assert [d.rank for d in decisions] == [1, 2, 3, 5, 4]
    (copied,) = [d for d in decisions if d.source is not None]
    assert (copied.member, copied.source) == (3, 0)  # one quarter of five: one each


@pytest.mark.unit
def test_dead_members_take_no_part() -> None:
    scores = [1.0, 9.0, 2.0, 8.0, 3.0]
    decisions = _decide(scores, alive=[True, False, True, True, True])
    assert 1 not in {d.member for d in decisions}
    (copied,) = [d for d in decisions if d.source is not None]
    assert (copied.member, copied.source) == (0, 3)  # the worst live one copies the best live
    assert not [d for d in _decide(scores, [True, False, True, True, False]) if d.source]


@pytest.mark.unit
def test_the_perturbed_q_stays_inside_the_range() -> None:
    rng = np.random.default_rng(0)
    for _ in range(50):
        decisions = decide(
            [1.0, 2.0, 3.0, 4.0], [1] * 4, [5.0, 0.5, 0.5, 5.0], [True] * 4, RANGE, rng
        )
        (copied,) = [d for d in decisions if d.source is not None]
        assert copied.member == 0 and copied.source == 3
        assert copied.q_after in (4.0, 5.0)  # 5 x 0.8, or 5 x 1.2 clipped to 5


@pytest.mark.unit
def test_initial_qs_are_log_spaced_over_the_range() -> None:
    qs = initial_qs(8, RANGE)
    assert qs[0] == pytest.approx(0.5) and qs[-1] == pytest.approx(5.0)
    ratios = np.diff(np.log(qs))
    assert np.allclose(ratios, ratios[0])
    # 0.1 * (1.7 / 0.1) is 1.7000000000000002, which the range check refused; 0.7 * (3 / 0.7)
    # is 2.9999999999999996, which populations started before the cap keep as their last q
    assert initial_qs(4, (0.7, 3.0))[-1] == 0.7 * (3.0 / 0.7)
    for q_range in [(0.1, 1.7), (0.3, 0.7), (0.6, 0.7)]:
        assert initial_qs(4, q_range)[::3] == list(q_range)
        seeds = [0, 1, 2, 3]
        configs, _ = make_run_configs("Hopper-v4", "Hopper", seeds, q_mode="auto", q_range=q_range)
        assert [c.q for c in configs][::3] == list(q_range)
    assert population_seed([0, 1]).entropy != population_seed([1, 0]).entropy


@pytest.mark.unit
def test_a_round_copies_q_clears_the_copys_scores_and_is_seeded() -> None:
    config = RunConfig(env="Hopper-v4", q=1.0, alpha=0.2, q_mode="auto", compile="off")
    rounds = []
    for _ in range(2):
        population = Population([0, 1, 2, 3], [0.5, 1.0, 2.0, 4.0], config)
        for k, episode_return in enumerate([10.0, 40.0, 30.0, 20.0]):
            population.episode_ended(k, episode_return)
        rounds.append(population.round([True] * 4, RANGE))
        assert population.returns[0] == type(population.returns[0])()  # member 0 copied
        assert population.qs[0] in (0.8, 1.2)
        row = population.row(20_000, rounds[-1][0])
        assert len(row) == len(PBT_COLUMNS) and row[1] == 0 and row[5] == 1
    assert rounds[0] == rounds[1]
    assert population.due(20_000) and not population.due(15_000)
    assert not population.due(config.learning_starts)
    # seeded: sixteen rounds' perturbations (each 0.8 or 1.2 of the copied q) repeat exactly
    # with the same seeds, and not with others (1 chance in 65,536)
    assert _perturbations([0, 1, 2, 3], config) == _perturbations([0, 1, 2, 3], config)
    assert _perturbations([0, 1, 2, 3], config) != _perturbations([4, 5, 6, 7], config)


def _perturbations(seeds: list[int], config: RunConfig) -> list[float]:
    """The q that member 0, always last, gets in each of sixteen rounds."""
    population = Population(seeds, [1.0, 1.0, 1.0, 1.0], config)
    qs = []
    for _ in range(16):
        for k, episode_return in enumerate([10.0, 40.0, 30.0, 20.0]):
            population.episode_ended(k, episode_return)
        qs.append(population.round([True] * 4, RANGE)[0].q_after)
    return qs


@pytest.mark.unit
def test_a_copy_gets_exactly_the_sources_learner_and_keeps_its_generator() -> None:
    config = RunConfig(
        env="Hopper-v4", q=1.0, alpha=0.2, alpha_mode="auto", compile="off", hidden_sizes=(8,)
    )
    agent = TacAgent(5, 2, config, [0, 1, 2], torch.device("cpu"), 1.0, [0.2, 0.2, 0.2])
    params = agent.chunks[0].params
    with torch.no_grad():
        params.exp_avg.normal_()
        params.exp_avg_sq.uniform_()
    generator_before = agent.generators[2].get_state()
    agent.copy_member(0, 2)
    source, copy = agent.member_state(0), agent.member_state(2)
    for part in ("params",):
        for name, tensor in source[part].items():
            assert torch.equal(tensor, copy[part][name]), name
    for key in ("exp_avg", "exp_avg_sq"):
        for name, tensor in source["adam"][key].items():
            assert torch.equal(tensor, copy["adam"][key][name]), name
    assert "log_alpha" in copy["params"]
    assert torch.equal(copy["generator"], generator_before)
    other = agent.member_state(1)
    assert not torch.equal(other["params"]["policy.weights.0"], copy["params"]["policy.weights.0"])


def _population_configs(
    seeds: tuple[int, ...] = (0, 1, 2, 3), **settings: object
) -> list[RunConfig]:
    run = {**TINY_RUN, **TINY_TAC, "learning_starts": 500, "pbt_every": 250, "compile": "off"}
    run |= {"total_steps": 1250, "hidden_sizes": (32,)}  # rounds at 750 and 1,000; small nets
    configs, _ = make_run_configs(
        "Hopper-v4", "Hopper", list(seeds), alphas=[0.2], q_mode="auto", **{**run, **settings}
    )
    return configs


@pytest.mark.smoke
def test_a_population_trains_audits_and_resumes_exactly(tmp_path: Path) -> None:
    whole = train(tmp_path / "whole", _population_configs())
    assert [o.state for o in whole] == ["complete"] * 4
    runs = [o.directory for o in whole]
    assert runs[0].parent.name == "qauto-a0.2-pbt250-ls500-h32-bs32"
    pbt = pd.concat([pd.read_csv(run / "pbt.csv") for run in runs])
    assert tuple(pbt.columns) == PBT_COLUMNS
    assert sorted(pbt["step"].unique()) == [750, 1000]  # none at the last step
    assert (pbt.groupby("step")["copied_from"].count() == 1).all()  # one quarter of four
    for run in runs:  # losses.csv shows each member's q as it went
        rows = pd.read_csv(run / "pbt.csv").set_index("step")
        losses = pd.read_csv(run / "losses.csv").set_index("step")
        for step, row in rows.iterrows():
            later = losses[losses.index > step]["q"]
            if len(later):
                assert later.iloc[0] == pytest.approx(row["q_after"])

    out = tmp_path / "resumed"
    for stop_at in (600, 900):  # in the warm-up's tail, and between rounds
        outcomes = train(out, _population_configs(), resume=True, stop=lambda s, a=stop_at: s >= a)
        assert {o.state for o in outcomes} == {"interrupted"}
    # the seeds in another order: each member keeps the q it started from (its place among the
    # first command's seeds set it; the resume was refused, naming a q the user never gave)
    resumed = train(out, _population_configs(seeds=(3, 2, 1, 0)), resume=True)
    for a, b in zip(runs, [o.directory for o in resumed], strict=True):
        assert_same_results(a, b)
        assert (a / "pbt.csv").read_text() == (b / "pbt.csv").read_text()


@pytest.mark.smoke
def test_a_population_resumes_only_as_a_whole(tmp_path: Path) -> None:
    """A population resumed without live members would rank without them: the resume names
    them (it named a q, where the members left out moved every other member's starting q)."""
    run = {**TINY_RUN, **TINY_TAC, "learning_starts": 500, "pbt_every": 250, "compile": "off"}
    run |= {"total_steps": 1250, "hidden_sizes": (16,), "eval_every": 0}

    def population(seeds: list[int]) -> list[RunConfig]:
        return make_run_configs("Hopper-v4", "Hopper", seeds, q_mode="auto", **run)[0]

    stopped = train(tmp_path, population(list(range(7))), stop=lambda step: step >= 600)
    before = {p: p.read_bytes() for o in stopped for p in o.directory.rglob("*") if p.is_file()}
    with pytest.raises(TacbenchError, match=r"resumes as a whole.*--seed 4, --seed 5, --seed 6"):
        train(tmp_path, population([0, 1, 2, 3]), resume=True)
    after = {p: p.read_bytes() for o in stopped for p in o.directory.rglob("*") if p.is_file()}
    assert after == before
    (stopped[6].directory / "config.json").rename(tmp_path / "moved-away.json")
    with pytest.raises(TacbenchError, match=r"its member \S+seed6 is gone \(no config.json\)"):
        check_whole_on_resume(stopped[0].directory, list(range(6)), 600)


@pytest.mark.smoke
def test_a_member_that_failed_after_the_checkpoint_is_named_on_resume(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Seed 2's losses turn NaN at step 800, after the checkpoint at 500 and the round at 750;
    the process crashes at 900. The population resumes from 500 without seed 2 (its run is
    over), so its round at 750 ranks three members where the uninterrupted one ranked four."""
    real, calls = loop.update, {"n": 0}

    def failing(*args: Any, **kwargs: Any) -> Any:
        calls["n"] += 1  # update n is at step 499 + n
        if calls["n"] == 401:
            raise RuntimeError("a bug in the update")
        metrics = real(*args, **kwargs)
        if calls["n"] == 301:
            metrics = metrics.clone()
            metrics[2, 0] = math.nan
        return metrics

    monkeypatch.setattr(loop, "update", failing)
    with pytest.raises(RuntimeError, match="a bug in the update"):
        train(tmp_path, _population_configs())
    monkeypatch.setattr(loop, "update", real)
    resumed = train(tmp_path, _population_configs(), resume=True)
    assert [o.state for o in resumed] == ["complete", "complete", "failed", "complete"]
    reason = json.loads((resumed[0].directory / "status.json").read_text())["reason"]
    assert "seed 2 failed at step 800, after step 500, and cannot rejoin" in reason


@pytest.mark.unit
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--q", "auto", "--seed", "0", "--seed", "1", "--seed", "2"], "at least 4 members"),
        (["--q", "auto", "--q", "1", *[f"--seed={s}" for s in range(4)]], "does not mix"),
        (["--q", "auto", "--q-range", "2,1", *[f"--seed={s}" for s in range(4)]], "--q-range"),
        (["--q", "auto", "--q-range", "0,5", *[f"--seed={s}" for s in range(4)]], "--q-range"),
        (["--q", "auto", "--q-range", "1,inf", *[f"--seed={s}" for s in range(4)]], "--q-range"),
        (  # a learned q above 1,000 is refused, as a fixed one is
            ["--q", "auto", "--q-range", "0.5,1e300", *[f"--seed={s}" for s in range(4)]],
            "HIGH <= 1000 (got (0.5, 1e+300)): above 1000 the density cap (below 1.02) makes "
            "ln_q flat",
        ),
        (["--q", "auto", "--q-range", "1", *[f"--seed={s}" for s in range(4)]], "--q-range"),
        (["--q", "auto", "--pbt-every", "0", *[f"--seed={s}" for s in range(4)]], "--pbt-every"),
        (["--q", "1", "--pbt-every", "500"], "add --q auto"),
        (["--algo", "td3", "--q", "auto"], "TAC's"),
    ],
)
def test_bad_population_requests_are_usage_errors(
    tmp_path: Path, args: list[str], message: str
) -> None:
    from click.testing import CliRunner

    result = CliRunner().invoke(cli, ["run", "--env", "Hopper-v4", *args, "--out", str(tmp_path)])
    assert result.exit_code == 2, result.output
    assert message in result.output
    assert not list(tmp_path.glob("runs/*"))
