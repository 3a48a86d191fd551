"""The paper's facts (:mod:`tacbench.paper`) against the paper's own LaTeX source: its two
appendix tables, its q grid and its task list, read from ``shared/paper/tsallis-rl-paper.tex``."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tacbench import paper
from tacbench.config import RunConfig

pytestmark = pytest.mark.unit

TEX = Path(__file__).resolve().parents[2] / "shared" / "paper" / "tsallis-rl-paper.tex"


@pytest.fixture(scope="module")
def tex() -> str:
    if not TEX.is_file():
        pytest.skip(f"the paper's source is not beside the repository ({TEX})")
    return TEX.read_text()


def _table_near(tex: str, text: str) -> list[list[str]]:
    """The rows of the tabular that contains ``text`` or is the first to follow it, each a list
    of stripped cells, without the rules and the header row."""
    at = tex.index(text)
    before = tex.rfind(r"\begin{tabular}", 0, at)
    start = (
        before if before > tex.rfind(r"\end{tabular}", 0, at) else tex.index(r"\begin{tabular}", at)
    )
    body = tex[start : tex.index(r"\end{tabular}", start)]
    rows = []
    for line in body.splitlines()[1:]:
        line = re.sub(r"\\(toprule|bottomrule|midrule)", "", line).strip().rstrip("\\").strip()
        if "&" in line:
            rows.append([cell.strip() for cell in line.split("&")])
    return rows[1:]


def _number(cell: str) -> float:
    """``$1e^{-3}$`` -> 0.001, ``$0.2$`` -> 0.2, ``$1e^{6}$`` -> 1e6, ``300`` -> 300."""
    text = cell.replace("$", "").strip()
    power = re.fullmatch(r"([\d.]+)e\^\{(-?\d+)\}", text)
    return float(power[1]) * 10 ** int(power[2]) if power else float(text)


def test_the_hyperparameter_table(tex: str) -> None:
    table = {name: value for name, value in _table_near(tex, "Hyperparameter Settings")}
    h = paper.HYPERPARAMETERS
    assert table["Optimizer"].startswith(h.optimizer)
    assert _number(table["Learning rate"]) == h.learning_rate
    assert _number(table["Discount factor"]) == h.gamma
    assert _number(table["Replay buffer size"]) == h.buffer_size
    assert _number(table["Number of Minimum samples in buffer"]) == h.min_samples
    assert _number(table["Number of Hidden Layers"]) == h.hidden_layers
    assert _number(table["Number of Hidden units"]) == h.hidden_units
    assert table["Activation function"].lower() == h.activation
    assert _number(table["Number of samples in minibatch"]) == h.batch_size
    assert _number(table["Moving average ratio"]) == h.tau
    assert tuple(int(s) for s in table["Seeds"].split()) == h.seeds == paper.SEEDS


def test_the_per_task_table(tex: str) -> None:
    rows = _table_near(tex, r"(Best) Entropic Index")
    assert len(rows) == len(paper.TASKS)
    for env, alpha, best in rows:
        task = env.removesuffix("-v2")
        facts = paper.TASK_FACTS[task]
        assert _number(alpha) == facts.alpha, task
        q, _, qualifier = best.partition("(")
        assert _number(q) == facts.best_q, task
        assert qualifier.rstrip(")").strip() == facts.qualifier, task


def test_the_q_grid_and_the_tasks(tex: str) -> None:
    grid = re.search(r"wide range of \$q\$ values: \$\\\{([^$]*)\\\}\$", tex)
    assert grid is not None
    assert tuple(float(q) for q in grid[1].split(",")) == paper.Q_GRID
    listed = re.search(r"MuJoCo simulators:\s*(.*?)\.\n", tex, re.S)
    assert listed is not None
    tasks = re.findall(r"(\w+)-v2", listed[1])
    assert tuple(tasks) == paper.TASKS  # the panel order is the order the text lists them in
    assert set(paper.ENV_IDS) == set(paper.TASKS)


def test_the_defaults_come_from_the_paper_module() -> None:
    config = RunConfig(env="Hopper-v4", q=1.0, alpha=0.2)
    h = paper.HYPERPARAMETERS
    assert (config.learning_rate, config.gamma, config.tau) == (h.learning_rate, h.gamma, h.tau)
    assert (config.batch_size, config.buffer_size) == (h.batch_size, h.buffer_size)
    assert config.hidden_sizes == h.hidden_sizes == paper.PROFILES["paper"]["hidden_sizes"]
    assert config.total_steps == paper.TOTAL_STEPS
    reference = RunConfig(env="Hopper-v4", q=1.0, alpha=0.2, profile="reference")
    for name, value in paper.PROFILES["reference"].items():
        assert getattr(reference, name) == value, name


def test_task_names() -> None:
    assert paper.paper_task("Hopper-v5") == "Hopper"
    assert paper.paper_task("HalfCheetah-v4") == "HalfCheetah"
    assert paper.paper_task("Pendulum-v1") is None
    assert paper.task_name("Humanoid-v4") == "Humanoid" and paper.task_name("Custom") == "Custom"
    assert paper.suite_task("hopper") == paper.suite_task("HOPPER-V4") == "Hopper"
    assert paper.suite_task("Hopper-v5") is None
    assert paper.suite_task("hopper-V5", "v5") == paper.suite_task("Hopper", "v5") == "Hopper"
    assert paper.suite_task("Hopper-v4", "v5") is None
    assert paper.SUITES["v4"] is paper.ENV_IDS
    assert dict(paper.SUITES["v5"]) == {task: f"{task}-v5" for task in paper.TASKS}
    assert paper.TASK_FACTS["Hopper"].best_q_label == "2 (slightly better)"
    assert paper.TASK_FACTS["HalfCheetah"].best_q_label == "1.5"
