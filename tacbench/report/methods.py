"""Method labels, their order, and one fixed colour and marker per method for every figure.

A *method* is what a figure line or a table row stands for: a TAC entropic index (``TAC q=1.5``),
SAC (TAC with q = 1, as the paper defines it), ``TAC q=auto`` (q learned by a population), a
baseline (``DDPG``), or ``TAC (best q)`` (the
best q other than 1 on each task, as in the paper's comparison figure). The paper's caption
fixes two styles: SAC is the red square line, TAC the blue pentagon line.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd
from matplotlib import colormaps
from matplotlib.colors import to_hex
from matplotlib.typing import LineStyleType

from tacbench.config import has_bf16_products
from tacbench.paper import Q_GRID

SAC_LABEL = "SAC (TAC q=1)"
BEST_Q_LABEL = "TAC (best q)"
Q_AUTO_LABEL = "TAC q=auto"  # --q auto: q learned by a population (training/pbt.py)
BASELINE_NAMES: dict[str, str] = {
    "ddpg": "DDPG",
    "td3": "TD3",
    "ppo": "PPO",
    "trpo": "TRPO",
    "sac-sb3": "SAC (SB3)",
}
"""Display names of the baselines, in the order the comparison figure lists them."""


@dataclass(frozen=True)
class Style:
    """How one method is drawn in every figure."""

    color: str
    marker: str
    linestyle: LineStyleType = "-"


_FIXED_STYLES: dict[str, Style] = {
    BEST_Q_LABEL: Style("#1f5fbf", "p"),  # paper: "TAC (blue pentagon line)"
    Q_AUTO_LABEL: Style("#111111", "P"),
    SAC_LABEL: Style("#d62728", "s"),  # paper: "SAC (red square line)"
    "DDPG": Style("#2ca02c", "^"),
    "TD3": Style("#ff7f0e", "v"),
    "PPO": Style("#9467bd", "D"),
    "TRPO": Style("#8c564b", "o"),
    "SAC (SB3)": Style("#e377c2", "X"),
}
_Q_MARKERS: dict[float, str] = {
    0.5: "v",
    0.7: "^",
    1.2: "o",
    1.5: "p",
    1.7: "h",
    2.0: "D",
    3.0: "X",
    5.0: "*",
}
_OTHER_COLOR = "#7f7f7f"
_VARIANT_LINESTYLES: tuple[LineStyleType, ...] = ("--", ":", "-.", (0, (5, 1, 1, 1)))


def tac_label(q: float) -> str:
    """Label of a TAC entropic index; q = 1 is SAC."""
    return SAC_LABEL if q == 1.0 else f"TAC q={q:g}"


def assign_methods(runs: pd.DataFrame) -> pd.Series:
    """One method label per run (index aligned with ``runs``).

    TAC runs are labelled by q (``TAC q=1.5``), so the paper's sweep, whose alpha differs between
    tasks, lines up across tasks. Where one task has several TAC variants with the same q (an
    alpha sweep, say), every run with that q is labelled with its variant too, and so is every
    run with bfloat16 products (``--matmul-precision bf16``, variant part ``-bf16``), a ``--q
    auto`` population's too, so that it never passes for a float32 run. A baseline is labelled
    by its name, with the variant added when the algorithm has several.
    """
    tac = runs[runs["algo"] == "tac"]
    per_task = tac.groupby(["env", "q"])["variant"].nunique()
    ambiguous = set(per_task[per_task > 1].index.get_level_values("q").astype(float))
    several = {str(algo) for algo, n in runs.groupby("algo")["variant"].nunique().items() if n > 1}
    learned = tac[tac["q"].isna()].groupby("env")["variant"].nunique()
    several_learned = bool((learned > 1).any())
    labels = []
    for algo, variant, q in zip(runs["algo"], runs["variant"], runs["q"], strict=True):
        if algo == "tac" and math.isnan(q):
            name, tagged = Q_AUTO_LABEL, several_learned or has_bf16_products(variant)
        elif algo == "tac":
            name, tagged = tac_label(q), q in ambiguous or has_bf16_products(variant)
        else:
            name, tagged = BASELINE_NAMES.get(algo, algo.upper()), algo in several
        labels.append(f"{name} [{variant}]" if tagged else name)
    return pd.Series(labels, index=runs.index, dtype=object)


def method_sort_key(method: str, q: float) -> tuple[int, float, str]:
    """TAC by q (SAC in its place), TAC q=auto, then TAC (best q), the baselines in paper
    order, the rest."""
    if method.startswith(Q_AUTO_LABEL):
        return 0, math.inf, method
    if not math.isnan(q):
        return 0, q, method
    if method == BEST_Q_LABEL:
        return 1, 0.0, method
    names = list(BASELINE_NAMES.values())
    base = method.split(" [")[0]
    return (2, float(names.index(base)), method) if base in names else (3, 0.0, method)


def _q_color(q: float) -> str:
    """A fixed colour per q: turbo from indigo to orange (red is SAC's), evenly over the paper
    grid without q = 1, log-interpolated between grid values."""
    others = [g for g in Q_GRID if g != 1.0]
    position = np.interp(np.log(q), np.log(others), np.arange(len(others)))
    return to_hex(colormaps["turbo"](0.05 + 0.7 * position / (len(others) - 1)))


def style_of(method: str, q: float = math.nan) -> Style:
    """The colour and marker of a method, identical in every figure and every report.

    A label carrying a variant (``TAC q=1.5 [q1.5-a0.1]``) keeps its method's colour and marker
    and gets a dashed line style chosen from the variant name.
    """
    base, _, variant = method.partition(" [")
    if base in _FIXED_STYLES:
        style = _FIXED_STYLES[base]
    elif not math.isnan(q):
        style = Style(_q_color(q), _Q_MARKERS.get(q, "o"))
    else:
        style = Style(_OTHER_COLOR, "o")
    if variant:
        dashes = _VARIANT_LINESTYLES[zlib.crc32(variant.encode()) % len(_VARIANT_LINESTYLES)]
        style = replace(style, linestyle=dashes)
    return style
