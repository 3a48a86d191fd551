"""The paper's theory figures, each written as a PNG beside the CSV of the numbers it plots.

- ``qexp_qlog_entropy``: exp_q, ln_q and the Tsallis entropy of a Bernoulli (paper fig.
  ``tsallis_ent_exm``).
- ``bandit_policies``: the optimal policy q-softmax(r) of the eight-arm bandit (figs.
  ``tsallis_bandit`` and ``q_alpha``).
- ``q_max_bounds``: q-max([c, 0]) between the bounds of theorem ``thm:bound`` (fig. ``qmx_bnd``).
- ``error_bounds``: J(pi*_q) of the grid world between the bounds of theorem
  ``thm:error_bounds`` (fig. ``error_bounds``).

Each ``*_table`` function returns the numbers as a tidy DataFrame, each ``plot_*`` draws one from
such a table, and :func:`write_figures` writes them all. Figures are built on
:class:`matplotlib.figure.Figure` (Agg canvas, no pyplot, no global state touched).
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import matplotlib
import matplotlib.style
import numpy as np
import pandas as pd
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure

from tacbench.errors import TacbenchError
from tacbench.theory.mdp import (
    GRID_ACTIONS,
    GRID_ALPHA,
    GRID_GAMMA,
    GRID_MAP,
    GRID_QS,
    error_bounds,
    grid_world,
)
from tacbench.theory.tsallis import exp_q, log_q, q_max, q_softmax, tsallis_entropy

ENTROPY_QS: tuple[float, ...] = (0.5, 1.0, 1.5, 2.0, 3.0, 5.0)
"""q values of the exp_q / ln_q / S_q figure (ours: the paper's image is not in its source)."""
BANDIT_REWARDS: tuple[float, ...] = (2.0, 2.0, 2.0, 2.0, 4.0, 4.0, 4.5, 5.0)
"""Rewards of the eight-arm bandit (REFERENCE.md)."""
BANDIT_QS: tuple[float, ...] = (0.5, 1.0, 2.0, 10.0)
"""q values of the bandit figure at alpha = 1 (REFERENCE.md; paper fig. ``tsallis_bandit``)."""
BANDIT_GRID_ALPHAS: tuple[float, ...] = (2.0, 1.5, 1.0, 0.5, 0.1)
"""alpha values of the appendix bandit grid (REFERENCE.md; paper fig. ``q_alpha``)."""
BANDIT_GRID_QS: tuple[float, ...] = (1.0, 1.5, 2.0, 3.0, 10.0)
"""q values of the appendix bandit grid (REFERENCE.md; paper fig. ``q_alpha``)."""
QMAX_QS: tuple[float, ...] = (1.0, 1.5, 2.0, 3.0, 5.0, 10.0)
"""q values of the q-max example (REFERENCE.md; paper fig. ``qmx_bnd``)."""
QMAX_C = np.linspace(-2.0, 2.0, 81)
"""c in [-2, 2] for f = [c, 0] (REFERENCE.md), in steps of 0.05."""

_STYLE = "seaborn-v0_8-whitegrid"
_RC: dict[str, Any] = {
    "font.size": 11,
    "axes.titlesize": 12,
    "axes.labelsize": 11,
    "legend.fontsize": 10,
}
_DPI = 120


def qexp_qlog_entropy_table() -> pd.DataFrame:
    """Columns ``function, q, x, value``: exp_q(x), ln_q(x) and S_q([1 - x, x]) per q in ENTROPY_QS.

    x is the argument for exp_q (in [-2, 1.5]) and ln_q (in [0.02, 3]), and ``P(X=1)`` for the
    Bernoulli entropy (in [0, 1]).
    """
    x_exp = np.linspace(-2.0, 1.5, 141)
    x_log = np.linspace(0.02, 3.0, 150)
    p_one = np.linspace(0.0, 1.0, 101)
    bernoulli = np.stack([1.0 - p_one, p_one], axis=-1)
    frames = []
    for q in ENTROPY_QS:
        for name, x, value in (
            ("exp_q", x_exp, exp_q(x_exp, q)),
            ("ln_q", x_log, log_q(x_log, q)),
            ("S_q", p_one, tsallis_entropy(bernoulli, q)),
        ):
            frames.append(pd.DataFrame({"function": name, "q": q, "x": x, "value": value}))
    return pd.concat(frames, ignore_index=True)


def bandit_policies_table() -> pd.DataFrame:
    """Columns ``q, alpha, action, reward, prob``: q_softmax(r, q, alpha) for the eight-arm bandit.

    Rows for q in BANDIT_QS at alpha = 1 and for the BANDIT_GRID_ALPHAS x BANDIT_GRID_QS grid,
    each (q, alpha) once.
    """
    pairs = [(q, 1.0) for q in BANDIT_QS]
    pairs += [(q, a) for a in BANDIT_GRID_ALPHAS for q in BANDIT_GRID_QS if (q, a) not in pairs]
    rewards = np.asarray(BANDIT_REWARDS)
    frames = [
        pd.DataFrame(
            {
                "q": q,
                "alpha": alpha,
                "action": np.arange(rewards.size),
                "reward": rewards,
                "prob": q_softmax(rewards, q, alpha),
            }
        )
        for q, alpha in pairs
    ]
    return pd.concat(frames, ignore_index=True)


def q_max_bounds_table() -> pd.DataFrame:
    """Columns ``q, c, q_max, lower, upper``: q-max([c, 0]) at alpha = 1 with theorem ``thm:bound``.

    ``lower = max(c, 0)`` and ``upper = max(c, 0) - ln_q(1/2)``.
    """
    f = np.stack([QMAX_C, np.zeros_like(QMAX_C)], axis=-1)
    frames = []
    for q in QMAX_QS:
        lower = f.max(axis=-1)
        frames.append(
            pd.DataFrame(
                {
                    "q": q,
                    "c": QMAX_C,
                    "q_max": q_max(f, q, 1.0),
                    "lower": lower,
                    "upper": lower - float(log_q(0.5, q)),
                }
            )
        )
    return pd.concat(frames, ignore_index=True)


def error_bounds_table() -> pd.DataFrame:
    """Columns ``q, J, lower_bound, upper_bound``: theorem ``thm:error_bounds``, grid world."""
    rows = error_bounds(grid_world(), GRID_QS, GRID_ALPHA)
    return pd.DataFrame(
        {
            "q": [r.q for r in rows],
            "J": [r.J for r in rows],
            "lower_bound": [r.lower_bound for r in rows],
            "upper_bound": [r.upper_bound for r in rows],
        }
    )


def _colors(n: int) -> list[tuple[float, ...]]:
    cmap = matplotlib.colormaps["viridis"]
    return [tuple(cmap(v)) for v in np.linspace(0.0, 0.9, n)]


def plot_qexp_qlog_entropy(table: pd.DataFrame) -> Figure:
    """Three panels: exp_q(x), ln_q(x), S_q of a Bernoulli, one line per q."""
    fig = Figure(figsize=(14, 4.3), layout="constrained")
    axes = fig.subplots(1, 3)
    panels = (
        ("exp_q", "x", r"$\exp_q(x)$", (0.0, 5.0)),
        ("ln_q", "x", r"$\ln_q(x)$", (-4.0, 2.0)),
        ("S_q", r"$P_1 = P(X=1)$", r"$S_q([1-P_1,\ P_1])$", None),
    )
    qs = sorted(table["q"].unique())
    for ax, (name, xlabel, ylabel, ylim) in zip(axes, panels, strict=True):
        for q, color in zip(qs, _colors(len(qs)), strict=True):
            part = table[(table["function"] == name) & (table["q"] == q)]
            ax.plot(part["x"], part["value"], color=color, lw=2, label=f"q = {q:g}")
        ax.set(xlabel=xlabel, ylabel=ylabel, title=ylabel)
        if ylim is not None:
            ax.set_ylim(*ylim)
    axes[0].legend(loc="upper left", title="entropic index")
    fig.suptitle(r"q-exponential, q-logarithm and Tsallis entropy of a Bernoulli (paper Fig. 1)")
    return fig


def plot_bandit_policies(table: pd.DataFrame) -> Figure:
    """Top: rewards and pi*_q at alpha = 1; bottom: the alpha x q grid of the appendix."""
    rewards = np.asarray(BANDIT_REWARDS)
    actions = np.arange(rewards.size)
    fig = Figure(figsize=(14, 15), layout="constrained")
    top, bottom = fig.subfigures(2, 1, squeeze=False, height_ratios=[1.0, 3.6])[:, 0]
    top_axes = top.subplots(1, len(BANDIT_QS) + 1)
    top_axes[0].bar(actions, rewards, color="0.45")
    top_axes[0].set(title="reward r(a)", xlabel="action a", ylabel="reward")
    for ax, q, color in zip(top_axes[1:], BANDIT_QS, _colors(len(BANDIT_QS)), strict=True):
        part = table[(table["q"] == q) & (table["alpha"] == 1.0)]
        ax.bar(part["action"], part["prob"], color=color)
        ax.set(title=f"q = {q:g}", xlabel="action a", ylim=(0, 1))
    top_axes[1].set_ylabel(r"$\pi^\star_q(a)$")
    for ax in top_axes:
        ax.set_xticks(actions)
    top.suptitle(
        r"Optimal policies $\pi^\star_q$ of the eight-arm bandit, $\alpha = 1$ (paper Fig. 2)"
    )

    grid = bottom.subplots(
        len(BANDIT_GRID_ALPHAS), len(BANDIT_GRID_QS), sharex=True, sharey=True, squeeze=False
    )
    colors = _colors(len(BANDIT_GRID_QS))
    for i, alpha in enumerate(BANDIT_GRID_ALPHAS):
        for j, q in enumerate(BANDIT_GRID_QS):
            ax = grid[i, j]
            part = table[(table["q"] == q) & (table["alpha"] == alpha)]
            ax.bar(part["action"], part["prob"], color=colors[j])
            ax.set_ylim(0, 1)
            ax.set_xticks(actions)
            if i == 0:
                ax.set_title(f"q = {q:g}")
            if j == 0:
                ax.set_ylabel(rf"$\alpha$ = {alpha:g}" + "\n" + r"$\pi^\star_q(a)$")
            if i == len(BANDIT_GRID_ALPHAS) - 1:
                ax.set_xlabel("action a")
    bottom.suptitle(r"Effect of $\alpha$ (rows) and q (columns) on $\pi^\star_q$ (appendix figure)")
    return fig


def plot_q_max_bounds(table: pd.DataFrame) -> Figure:
    """One panel per q: q-max([c, 0]) over c with the band between its two bounds."""
    qs = sorted(table["q"].unique())
    ncols = 3
    nrows = -(-len(qs) // ncols)
    fig = Figure(figsize=(13, 4.0 * nrows), layout="constrained")
    axes = fig.subplots(nrows, ncols, sharex=True, sharey=True, squeeze=False).ravel()
    for ax, q in zip(axes, qs, strict=False):
        part = table[table["q"] == q]
        ax.fill_between(part["c"], part["lower"], part["upper"], color="C0", alpha=0.15)
        ax.plot(part["c"], part["upper"], "--", color="C3", lw=1.5, label=r"$\max f - \ln_q(1/2)$")
        ax.plot(part["c"], part["q_max"], color="C0", lw=2.5, label="q-max f")
        ax.plot(part["c"], part["lower"], ":", color="k", lw=1.5, label=r"$\max f$")
        ax.set_title(f"q = {q:g}")
    for ax in axes.reshape(nrows, ncols)[-1]:
        ax.set_xlabel("c")
    for ax in axes.reshape(nrows, ncols)[:, 0]:
        ax.set_ylabel(r"value for $f = [c, 0]$")
    for ax in axes[len(qs) :]:
        ax.set_visible(False)
    axes[0].legend(loc="upper left")
    fig.suptitle(r"q-maximum of $f = [c, 0]$ and the bounds of its theorem ($\alpha = 1$)")
    return fig


def plot_error_bounds(table: pd.DataFrame) -> Figure:
    """Left: the grid world; right: J(pi*_q) against q with the theorem's bounds."""
    fig = Figure(figsize=(13, 5.2), layout="constrained")
    ax_map, ax = fig.subplots(1, 2, width_ratios=[1.0, 1.7])
    kinds = "SFHG"
    cells = np.array([[kinds.index(c) for c in row] for row in GRID_MAP])
    cmap = ListedColormap(["#a6cee3", "#a6cee3", "#1f3b73", "#f2c12e"])
    ax_map.imshow(cells, cmap=cmap, vmin=0, vmax=3)
    labels = {"S": "S\nstart", "F": "", "H": "H\n-0.5", "G": "G\n+2"}
    for (i, j), k in np.ndenumerate(cells):
        color = "white" if kinds[k] == "H" else "black"
        ax_map.text(j, i, labels[kinds[k]], ha="center", va="center", color=color, fontsize=12)
    ax_map.set_xticks(np.arange(cells.shape[1] + 1) - 0.5, minor=True)
    ax_map.set_yticks(np.arange(cells.shape[0] + 1) - 0.5, minor=True)
    ax_map.grid(which="minor", color="white", lw=2)
    ax_map.grid(which="major", visible=False)
    ax_map.tick_params(which="both", length=0, labelbottom=False, labelleft=False)
    ax_map.set_title(
        f"grid world: actions {', '.join(GRID_ACTIONS)}\nintended move 0.8, each side 0.1"
    )

    ax.fill_between(table["q"], table["lower_bound"], table["upper_bound"], color="C0", alpha=0.12)
    ax.plot(
        table["q"], table["upper_bound"], "--", color="C3", lw=2, label=r"upper: $J(\pi^\star)$"
    )
    ax.plot(table["q"], table["J"], "o-", color="C0", lw=2.5, ms=7, label=r"$J(\pi^\star_q)$")
    ax.plot(
        table["q"],
        table["lower_bound"],
        "s:",
        color="k",
        lw=1.5,
        ms=5,
        label=r"lower: $J(\pi^\star) + \alpha\,\ln_q(1/|A|)\,/\,(1-\gamma)$",
    )
    ax.set(
        xlabel="entropic index q (log scale)",
        ylabel="expected discounted reward J from S",
        title=rf"Performance error bounds ($\gamma$ = {GRID_GAMMA:g}, $\alpha$ = {GRID_ALPHA:g})",
    )
    ax.set_xscale("log")
    ax.set_xticks(table["q"], [f"{q:g}" for q in table["q"]])
    ax.minorticks_off()
    ax.legend(loc="lower right")
    return fig


_FIGURES = (
    ("qexp_qlog_entropy", qexp_qlog_entropy_table, plot_qexp_qlog_entropy),
    ("bandit_policies", bandit_policies_table, plot_bandit_policies),
    ("q_max_bounds", q_max_bounds_table, plot_q_max_bounds),
    ("error_bounds", error_bounds_table, plot_error_bounds),
)


def write_figures(out_dir: str | Path) -> list[Path]:
    """Write ``<name>.png`` and ``<name>.csv`` of each figure into out_dir (created if missing).

    Returns the written paths in order; raises TacbenchError if out_dir is not a usable directory.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise TacbenchError(f"--out {out} exists and is not a directory; pick a directory path.")
    try:  # a file written there, before any figure is: a read-only folder said nothing
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as err:
        raise TacbenchError(
            f"cannot create or write the output directory {out}: {err.strerror}; pick another "
            "--out."
        ) from None
    paths = [out / f"{name}.{kind}" for name, _, _ in _FIGURES for kind in ("csv", "png")]
    blocked = [path.name for path in paths if path.exists() and not path.is_file()]
    if blocked:  # found before any figure is written, not after some
        raise TacbenchError(
            f"{out} holds {', '.join(blocked)} as a folder, where a figure's file goes; nothing "
            "was written. Move it away, or pick another --out."
        )
    written = []
    with matplotlib.style.context([_STYLE, _RC]):
        for name, make_table, plot in _FIGURES:
            table = make_table()
            csv_path, png_path = out / f"{name}.csv", out / f"{name}.png"
            table.to_csv(csv_path, index=False, float_format="%.10g")
            plot(table).savefig(png_path, dpi=_DPI)
            written += [png_path, csv_path]
    return written
