"""Figures: the expected panels, lines, styles and rows (matplotlib objects, not pixels)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import to_hex
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from tacbench.report import Report, ReportOptions, analyse, plots
from tacbench.report.methods import BEST_Q_LABEL, SAC_LABEL, style_of
from tests.report_fixtures import synthetic_tree

pytestmark = pytest.mark.unit

TASKS = ("Hopper-v4", "Ant-v4", "HalfCheetah-v4", "Humanoid-v4")


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> Report:
    root = synthetic_tree(
        tmp_path_factory.mktemp("plots"),
        tasks=TASKS,
        qs=(0.5, 1.0, 1.5, 2.0),
        baselines=("ddpg", "td3"),
        seeds=3,
        n_eval=8,
        spread=0.1,
    )
    return analyse(ReportOptions(results=root, out=root / "report", reps=200))


def _panels(fig: Figure) -> list[Axes]:
    return [ax for ax in fig.axes if ax.get_title()]


def _lines(ax: Axes) -> dict[str, Line2D]:
    return {str(line.get_label()): line for line in ax.get_lines()}


def test_every_figure_is_made(report: Report) -> None:
    assert set(report.figures) == {
        "q_sweep",
        "comparison",
        "intervals",
        "intervals_per_task",
        "improvement",
        "profiles",
    }


def test_q_sweep_has_one_panel_per_task_in_paper_order_and_one_line_per_q(
    report: Report,
) -> None:
    panels = _panels(report.figures["q_sweep"])
    assert [ax.get_title() for ax in panels] == [
        "HalfCheetah-v4",
        "Ant-v4",
        "Humanoid-v4",
        "Hopper-v4",
    ]
    for ax in panels:
        assert list(_lines(ax)) == ["TAC q=0.5", SAC_LABEL, "TAC q=1.5", "TAC q=2"]
        assert len(ax.collections) == 4  # one +/- std band per line
        assert ax.get_xlabel() == "environment steps"
        assert ax.get_ylabel() == "evaluation return"


def test_q_sweep_lines_are_the_seed_means(report: Report) -> None:
    ax = _panels(report.figures["q_sweep"])[0]
    line = _lines(ax)["TAC q=1.5"]
    curve = report.curves[
        (report.curves["env"] == "HalfCheetah-v4") & (report.curves["method"] == "TAC q=1.5")
    ]
    np.testing.assert_allclose(line.get_ydata(), curve["mean"])
    np.testing.assert_allclose(line.get_xdata(), 5000 * np.arange(1, 9))


def test_comparison_has_best_q_sac_and_baselines_with_fixed_styles(report: Report) -> None:
    panels = _panels(report.figures["comparison"])
    assert len(panels) == len(TASKS)
    for ax in panels:
        lines = _lines(ax)
        assert list(lines) == [BEST_Q_LABEL, SAC_LABEL, "DDPG", "TD3"]
        for label, line in lines.items():
            style = style_of(label, report.qs[label])
            assert to_hex(line.get_color()) == style.color
            assert line.get_marker() == style.marker
    sac_sweep = _lines(_panels(report.figures["q_sweep"])[0])[SAC_LABEL]
    sac_comparison = _lines(panels[0])[SAC_LABEL]
    assert sac_sweep.get_color() == sac_comparison.get_color() == "#d62728"
    best = _lines(panels[0])[BEST_Q_LABEL]
    q15 = _lines(_panels(report.figures["q_sweep"])[0])["TAC q=1.5"]
    np.testing.assert_array_equal(best.get_ydata(), q15.get_ydata())


def test_interval_figures_have_one_row_per_method(report: Report) -> None:
    iqm, mean = _panels(report.figures["intervals"])
    assert (iqm.get_title(), mean.get_title()) == ("IQM", "Mean")
    labels = [t.get_text() for t in iqm.get_yticklabels()]
    assert labels == report.methods
    assert len(iqm.collections) == len(report.methods)  # one interval bar per method
    per_task = _panels(report.figures["intervals_per_task"])
    assert [ax.get_title() for ax in per_task] == report.envs


def test_improvement_figure_has_an_all_tasks_panel_first(report: Report) -> None:
    panels = _panels(report.figures["improvement"])
    assert [ax.get_title() for ax in panels] == ["all tasks", *report.envs]
    labels = [t.get_text() for t in panels[0].get_yticklabels()]
    assert labels == ["TAC q=0.5", "TAC q=1.5", "TAC q=2", BEST_Q_LABEL]


def test_profiles_split_the_sweep_from_the_comparison(report: Report) -> None:
    sweep, comparison = _panels(report.figures["profiles"])
    assert list(_lines(sweep)) == ["TAC q=0.5", SAC_LABEL, "TAC q=1.5", "TAC q=2"]
    assert list(_lines(comparison)) == [BEST_Q_LABEL, SAC_LABEL, "DDPG", "TD3"]
    assert sweep.get_xlim() == (0.0, 1.0)


def test_train_metric_labels_the_axis(tmp_path: Path) -> None:
    synthetic_tree(tmp_path, tasks=("Ant-v4",), qs=(1.0, 1.5), baselines=(), seeds=2, n_eval=4)
    report = analyse(ReportOptions(results=tmp_path, out=tmp_path / "r", metric="train", reps=100))
    ax = _panels(report.figures["q_sweep"])[0]
    assert ax.get_ylabel() == "training return"
    assert "improvement" in report.figures and len(_panels(report.figures["improvement"])) == 1


def test_reports_without_a_q_sweep(tmp_path: Path) -> None:
    synthetic_tree(tmp_path, tasks=("Ant-v4",), qs=(), baselines=("td3", "ddpg"), seeds=1, n_eval=3)
    report = analyse(ReportOptions(results=tmp_path, out=tmp_path / "r", reps=100))
    assert set(report.figures) == {"comparison", "intervals", "intervals_per_task", "profiles"}
    assert report.best_q.empty and report.improvement.empty
    assert list(_lines(_panels(report.figures["comparison"])[0])) == ["DDPG", "TD3"]


@pytest.mark.parametrize("tasks", [("HalfCheetah-v4",), (*TASKS, "Swimmer-v4", "Pusher-v5")])
def test_every_figure_is_whole_with_one_task_and_with_six(
    tmp_path: Path, tasks: tuple[str, ...]
) -> None:
    # the nine q of the paper and all five baselines: the widest legends the report draws
    root = synthetic_tree(
        tmp_path,
        tasks=tasks,
        qs=(0.5, 0.7, 1.0, 1.2, 1.5, 1.7, 2.0, 3.0, 5.0),
        baselines=("ddpg", "td3", "ppo", "trpo", "sac-sb3"),
        seeds=2,
        n_eval=4,
    )
    figures = analyse(ReportOptions(results=root, out=root / "report", reps=100)).figures
    for name, fig in figures.items():
        _assert_whole(name, fig)


def _assert_whole(name: str, fig: Figure) -> None:
    """Nothing of ``fig`` lies off the page, and its shared legend lies below every panel."""
    renderer = FigureCanvasAgg(fig).get_renderer()
    page = fig.bbox
    drawn = [*fig.legends, *fig.axes, *(ax.get_legend() for ax in fig.axes), fig._suptitle]
    for artist in (a for a in drawn if a is not None):
        box = artist.get_tightbbox(renderer) if isinstance(artist, Axes) else None
        box = box or artist.get_window_extent(renderer)
        assert box.x0 >= -1 and box.x1 <= page.x1 + 1, f"{name}: {artist} is cut off"
        assert box.y0 >= -1 and box.y1 <= page.y1 + 1, f"{name}: {artist} is cut off"
    for legend in fig.legends:  # the shared legend sits below every panel's tick labels
        top = legend.get_window_extent(renderer).y1
        assert all(top <= ax.get_tightbbox(renderer).y0 + 1 for ax in fig.axes), name


def test_a_profile_figure_of_many_settings_is_whole() -> None:
    """A report of every committed study has about 30 methods in its profiles (q = 1 in each
    setting of the authors' versions): each panel's legend to its right ran over the next panel
    and off the page's foot. One legend below both now grows the figure."""
    methods = [f"SAC (TAC q=1) [q1-a0.2-setting{k}]" for k in range(24)] + ["DDPG", "TD3"]
    tau = np.linspace(0, 1, 5)
    profiles = pd.DataFrame(
        [
            {"method": m, "tau": t, "fraction": 1 - t, "low": 0.9 - t, "high": 1.0}
            for m in methods
            for t in tau
        ]
    )
    groups = {"TAC entropic indices": methods[:20], "Comparison": methods[16:]}
    fig = plots.profile_figure(profiles, groups, {}, "Performance profiles")
    _assert_whole("profiles", fig)
    assert [t.get_text() for t in fig.legends[0].get_texts()] == methods  # each method once
