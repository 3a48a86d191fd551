"""``tacbench envs``: the paper's task suite."""

from __future__ import annotations

import click

from tacbench import paper


@click.command(name="envs")
@click.option(
    "--suite",
    type=click.Choice(list(paper.SUITES)),
    default=paper.DEFAULT_SUITE,
    show_default=True,
    help="The tasks' Gymnasium version: v4 (the studies') or v5 (Gymnasium's recommendation).",
)
def envs_command(suite: str) -> None:
    """List the paper's task suite with its Gymnasium ids and the paper's alpha and best q."""
    from tacbench.envs import suite_table

    rows = suite_table(suite)
    width = max(len("best q"), *(len(paper.TASK_FACTS[r["task"]].best_q_label) for r in rows))
    header = (
        f"{'task':<12} {'env':<16} {'obs':>4} {'act':>4} {'limit':>6} {'alpha':>6}  "
        f"{'best q':<{width}}  loads"
    )
    click.echo(header)
    for row in rows:
        facts = paper.TASK_FACTS[row["task"]]
        click.echo(
            f"{row['task']:<12} {row['env']:<16} {row['obs']!s:>4} {row['act']!s:>4} "
            f"{row['limit']!s:>6} {facts.alpha:>6g}  {facts.best_q_label:<{width}}  {row['ok']}"
        )
    click.echo(
        "alpha and best q: paper appendix, per-task table"
        + (
            f" (tuned by the paper on the v2 tasks; carried over to {suite} unchanged)"
            if suite != paper.DEFAULT_SUITE
            else ""
        )
        + ". Any other registered Gymnasium id with continuous actions also works with --env "
        "(default q = 1, alpha = 0.2)."
    )
