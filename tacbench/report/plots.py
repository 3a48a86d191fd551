"""The report's figures. Each function builds and returns a matplotlib Figure; :func:`save` writes.

Figures are built with matplotlib's object API (no pyplot): no global figure registry, no
backend switch, nothing to close.

Every method has one colour and marker in every figure (:func:`tacbench.report.methods.style_of`).
Panels follow the paper's task order, at most three per row (the appendix layout).
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, BinaryIO

import pandas as pd
import seaborn as sns
from matplotlib import rc_context
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import EngFormatter, MaxNLocator
from matplotlib.typing import RcKeyType

from tacbench.report.methods import style_of

PANEL_WIDTH = 4.3
PANEL_HEIGHT = 3.2
MAX_COLUMNS = 3
MARKERS_PER_LINE = 8
MAX_LEGEND_COLUMNS = 6
LEGEND_ROW_HEIGHT = 0.3  # inches per row of the shared legend


def _theme() -> dict[RcKeyType, Any]:
    """The seaborn look, applied per figure so the caller's rcParams stay untouched."""
    return {**sns.axes_style("whitegrid"), **sns.plotting_context("notebook", font_scale=0.9)}


def _panels(
    count: int, height: float = PANEL_HEIGHT, title_height: float = 0.9
) -> tuple[Figure, list[Axes]]:
    rows = math.ceil(count / MAX_COLUMNS)
    columns = math.ceil(count / rows)
    fig = Figure(figsize=(PANEL_WIDTH * columns, height * rows + title_height))
    grid = fig.subplots(rows, columns, squeeze=False)
    axes = list(grid.ravel())
    for extra in axes[count:]:
        extra.remove()
    return fig, axes[:count]


def _legend(fig: Figure, methods: Sequence[str], qs: Mapping[str, float]) -> int:
    """The shared legend at the bottom, in as many columns (at most 6) as fit the figure's
    width, measured with the figure's renderer; returns its number of rows."""
    handles = [
        Line2D(
            [],
            [],
            color=style_of(m, qs.get(m, math.nan)).color,
            marker=style_of(m, qs.get(m, math.nan)).marker,
            linestyle=style_of(m, qs.get(m, math.nan)).linestyle,
            label=m,
        )
        for m in methods
    ]
    renderer = FigureCanvasAgg(fig).get_renderer()
    columns = min(len(handles), MAX_LEGEND_COLUMNS)
    while True:
        legend = fig.legend(
            handles=handles,
            loc="lower center",
            ncol=columns,
            frameon=False,
            bbox_to_anchor=(0.5, 0.0),
        )
        if columns == 1 or legend.get_window_extent(renderer).width <= 0.98 * fig.bbox.width:
            return math.ceil(len(handles) / columns)
        legend.remove()
        columns -= 1


def _title(fig: Figure, title: str) -> None:
    """A bold figure title, wrapped to the figure's width."""
    fig.suptitle(textwrap.fill(title, width=int(fig.get_figwidth() * 8)), fontweight="bold")


def _finish(fig: Figure, title: str, legend_rows: int) -> Figure:
    """Title, and the figure made taller by the bottom legend's rows so the panels keep their
    size."""
    _title(fig, title)
    legend_height = LEGEND_ROW_HEIGHT * legend_rows
    fig.set_figheight(fig.get_figheight() + legend_height)
    fig.tight_layout(rect=(0, legend_height / fig.get_figheight(), 1, 1))
    return fig


def curve_figure(
    curves: pd.DataFrame,
    envs: Sequence[str],
    methods: Sequence[str],
    qs: Mapping[str, float],
    title: str,
    ylabel: str,
) -> Figure:
    """One panel per task, one line per method: mean over seeds with a +/- 1 std band.

    ``curves`` is :func:`tacbench.report.curves.seed_curves` output. A panel's legend entry is
    shared at the bottom of the figure; methods without data on a task are simply absent there.
    """
    with rc_context(_theme()):
        fig, axes = _panels(len(envs), title_height=0.6)  # _finish adds the legend's height
        for ax, env in zip(axes, envs, strict=True):
            task = curves[curves["env"] == env]
            for method in methods:
                line = task[task["method"] == method]
                if line.empty:
                    continue
                style = style_of(method, qs.get(method, math.nan))
                x = line["step"].to_numpy()
                mean = line["mean"].to_numpy()
                spread = line["std"].fillna(0.0).to_numpy()
                ax.plot(
                    x,
                    mean,
                    color=style.color,
                    marker=style.marker,
                    linestyle=style.linestyle,
                    markevery=max(1, len(x) // MARKERS_PER_LINE),
                    markersize=5,
                    linewidth=1.6,
                    label=method,
                )
                ax.fill_between(
                    x, mean - spread, mean + spread, color=style.color, alpha=0.15, linewidth=0
                )
            ax.set_title(env)
            ax.set_xlabel("environment steps")
            ax.set_ylabel(ylabel)
            ax.xaxis.set_major_formatter(EngFormatter(sep=""))
            ax.xaxis.set_major_locator(MaxNLocator(5))
        return _finish(fig, title, _legend(fig, methods, qs))


def _interval_rows(
    ax: Axes,
    table: pd.DataFrame,
    methods: Sequence[str],
    qs: Mapping[str, float],
    column: str,
) -> None:
    """A thick translucent bar over the 95 % interval and the method's marker at the estimate.

    rliable draws a bar and a tick; the marker keeps a method visible when its interval is
    narrower than a pixel.
    """
    present = set(table["method"])
    rows = [m for m in methods if m in present]
    for y, method in enumerate(rows):
        row = table[table["method"] == method].iloc[0]
        style = style_of(method, qs.get(method, math.nan))
        ax.hlines(
            y,
            row[f"{column}_low"],
            row[f"{column}_high"],
            color=style.color,
            linewidth=8,
            alpha=0.4,
        )
        ax.plot(
            row[column],
            y,
            marker=style.marker,
            color=style.color,
            markeredgecolor="black",
            markersize=7,
            linestyle="none",
        )
    ax.set_yticks(range(len(rows)), rows)
    ax.set_ylim(len(rows) - 0.5, -0.5)
    ax.margins(x=0.05)
    ax.xaxis.set_major_locator(MaxNLocator(5))
    ax.grid(True, axis="x", alpha=0.4)
    ax.grid(False, axis="y")


def interval_figure(
    aggregate: pd.DataFrame, methods: Sequence[str], qs: Mapping[str, float], title: str
) -> Figure:
    """IQM and mean of normalised scores over all tasks, one row per method, 95 % intervals."""
    with rc_context(_theme()):
        height = 1.6 + 0.32 * len(methods)
        fig = Figure(figsize=(11, height))
        axes = fig.subplots(1, 2, sharey=True)
        for ax, column, name in zip(axes, ("iqm", "mean"), ("IQM", "Mean"), strict=True):
            _interval_rows(ax, aggregate, methods, qs, column)
            ax.set_title(name)
            ax.set_xlabel("normalised score")
        _title(fig, title)
        fig.tight_layout()
        return fig


def task_interval_figure(
    per_task: pd.DataFrame,
    envs: Sequence[str],
    methods: Sequence[str],
    qs: Mapping[str, float],
    title: str,
) -> Figure:
    """Per task: IQM of the final return over seeds with 95 % intervals, one row per method."""
    with rc_context(_theme()):
        rows = max(len(set(per_task[per_task["env"] == e]["method"])) for e in envs)
        fig, axes = _panels(len(envs), height=1.3 + 0.3 * rows)
        for ax, env in zip(axes, envs, strict=True):
            _interval_rows(ax, per_task[per_task["env"] == env], methods, qs, "iqm")
            ax.set_title(env)
            ax.set_xlabel("final return (IQM over seeds)")
        _title(fig, title)
        fig.tight_layout()
        return fig


def improvement_figure(
    improvement: pd.DataFrame,
    panels: Sequence[str],
    methods: Sequence[str],
    qs: Mapping[str, float],
    title: str,
) -> Figure:
    """P(method > q = 1) with 95 % intervals; one panel per entry of ``panels`` (task or all)."""
    with rc_context(_theme()):
        rows = max(len(improvement[improvement["env"] == p]) for p in panels)
        fig, axes = _panels(len(panels), height=1.3 + 0.3 * rows)
        renamed = improvement.rename(columns={"p": "p", "low": "p_low", "high": "p_high"})
        for ax, panel in zip(axes, panels, strict=True):
            _interval_rows(ax, renamed[renamed["env"] == panel], methods, qs, "p")
            ax.axvline(0.5, color="grey", linestyle="--", linewidth=1)
            ax.set_xlim(-0.03, 1.03)
            ax.set_title(panel)
            ax.set_xlabel("P(method > q = 1)")
        _title(fig, title)
        fig.tight_layout()
        return fig


def profile_figure(
    profiles: pd.DataFrame,
    groups: Mapping[str, Sequence[str]],
    qs: Mapping[str, float],
    title: str,
) -> Figure:
    """Performance profiles (fraction of runs above tau) with 95 % bands, one panel per group,
    and the groups' methods in one legend below (a report of many settings has dozens)."""
    with rc_context(_theme()):
        names = [name for name, members in groups.items() if members]
        fig = Figure(figsize=(6.0 * len(names), 4.6))
        axes = fig.subplots(1, len(names), squeeze=False)
        for ax, name in zip(axes[0], names, strict=True):
            for method in groups[name]:
                line = profiles[profiles["method"] == method]
                style = style_of(method, qs.get(method, math.nan))
                tau = line["tau"].to_numpy()
                ax.plot(
                    tau,
                    line["fraction"],
                    color=style.color,
                    linestyle=style.linestyle,
                    marker=style.marker,
                    markevery=max(1, len(tau) // MARKERS_PER_LINE),
                    markersize=5,
                    label=method,
                )
                ax.fill_between(tau, line["low"], line["high"], color=style.color, alpha=0.15)
            ax.set_title(name)
            ax.set_xlabel(r"normalised score $\tau$")
            ax.set_ylabel(r"fraction of runs with score $> \tau$")
            ax.set_xlim(0, 1)
            ax.set_ylim(0, 1.02)
        methods = list(dict.fromkeys(m for name in names for m in groups[name]))
        return _finish(fig, title, _legend(fig, methods, qs))


def save(fig: Figure, target: Path | BinaryIO, fmt: str | None = None, dpi: int = 110) -> None:
    """Write a figure to a path (format from its suffix) or a binary stream (``fmt`` needed).

    Timestamps are left out of the file so the same data gives the same bytes.
    """
    kind = fmt or (target.suffix.lstrip(".") if isinstance(target, Path) else "png")
    with rc_context(_theme()):
        fig.savefig(target, format=kind, dpi=dpi, metadata=_METADATA[kind])


_METADATA: dict[str, dict[str, str | None]] = {
    "png": {"Software": None},
    "svg": {"Date": None},
    "pdf": {"CreationDate": None},
}


def q_trajectory_figure(trajectories: pd.DataFrame, envs: Sequence[str], title: str) -> Figure:
    """TAC q=auto: each member's q over training (log scale), one panel per task, one colour
    per population."""
    populations = list(dict.fromkeys(trajectories["population"]))
    colours = dict(zip(populations, sns.color_palette("tab10", len(populations)), strict=True))
    with rc_context(_theme()):
        fig, axes = _panels(len(envs), title_height=0.6)
        for ax, env in zip(axes, envs, strict=True):
            task = trajectories[trajectories["env"] == env]
            for (population, _seed), member in task.groupby(["population", "seed"], sort=False):
                ax.plot(  # a losses row's q held since the previous row
                    member["step"],
                    member["q"],
                    color=colours[population],
                    linewidth=1,
                    alpha=0.7,
                    drawstyle="steps-pre",
                )
            ax.set_yscale("log")
            ax.minorticks_off()
            ax.set_yticks([0.5, 1, 2, 5], labels=["0.5", "1", "2", "5"])
            ax.set_title(env)
            ax.set_xlabel("environment steps")
            ax.set_ylabel("q")
        handles = [Line2D([], [], color=colours[p], label=p) for p in populations]
        fig.legend(handles=handles, loc="lower center", ncol=min(len(handles), 3), frameon=False)
        return _finish(fig, title, math.ceil(len(handles) / 3))
