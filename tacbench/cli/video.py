"""``tacbench video``: render episodes of a run's latest deterministic policy to MP4 or GIF."""

from __future__ import annotations

from pathlib import Path

import click

from tacbench.errors import TacbenchError


@click.command()
@click.argument("run_dir", type=click.Path(file_okay=False, exists=True, path_type=Path))
@click.option(
    "--out",
    type=click.Path(dir_okay=False, path_type=Path),
    required=True,
    help="The video to write: FILE.mp4 or FILE.gif (replaced if it exists).",
)
@click.option(
    "--episodes",
    type=click.IntRange(min=1, max=1000),
    default=1,
    show_default=True,
    help="Episodes to render, one after another, on the evaluation seeds of the policy's step.",
)
@click.option(
    "--max-steps",
    type=click.IntRange(min=1),
    default=None,
    help="Cut each episode after this many steps.  [default: the task's time limit]",
)
@click.option(
    "--width",
    type=click.IntRange(min=16, max=4096),
    default=480,
    show_default=True,
    help="Frame width in pixels (an MP4's: a multiple of 8).",
)
@click.option(
    "--height",
    type=click.IntRange(min=16, max=4096),
    default=360,
    show_default=True,
    help="Frame height in pixels (an MP4's: a multiple of 8).",
)
@click.option(
    "--fps", type=click.IntRange(min=1), default=30, show_default=True, help="Frames per second."
)
def video(
    run_dir: Path,
    out: Path,
    episodes: int,
    max_steps: int | None,
    width: int,
    height: int,
    fps: int,
) -> None:
    """Render RUN_DIR's policy at its newest checkpoint (deterministic, the evaluation's
    seeds) with MuJoCo's offscreen renderer (EGL or OSMesa, whichever works here)."""
    from tacbench import envs, memory
    from tacbench import video as rendering  # torch, SB3 and imageio only when this runs
    from tacbench.runs.files import check_writable

    kind = out.suffix.lower()  # hopper.MP4 as hopper.mp4
    if kind not in rendering.FORMATS:
        raise TacbenchError(f"--out must end in {' or '.join(rendering.FORMATS)}, not {out.name!r}")
    if kind == ".mp4":
        for flag, size in (("--width", width), ("--height", height)):
            if size % rendering.MP4_BLOCK:
                low = size - size % rendering.MP4_BLOCK
                raise TacbenchError(
                    f"{flag} {size}: an MP4's frame sides are multiples of {rendering.MP4_BLOCK} "
                    f"(H.264's blocks); use {low} or {low + rendering.MP4_BLOCK}, or a .gif"
                )
    check_writable(out.parent)
    backend = rendering.choose_gl_backend()
    policy = rendering.load_policy(run_dir)
    if kind == ".gif":  # Pillow writes a GIF at the end: its frames are all kept
        steps = max_steps or envs.env_info(policy.env).max_episode_steps
        memory.check_fits(
            {"the GIF's frames": episodes * (steps + 1) * width * height},
            "--episodes, --max-steps, --width or --height (or write an .mp4, which streams)",
            "this GIF",
        )
    click.echo(
        f"rendering {episodes} episode(s) of {policy.algo} on {policy.env}, seed {policy.seed}, "
        f"checkpoint at step {policy.step:,} ({backend})"
    )
    returns: list[float] = []
    frames = rendering.episode_frames(policy, episodes, width, height, max_steps, returns)
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_name(f".{out.stem}.partial{out.suffix}")
    try:
        count = rendering.write_video(frames, partial, fps)
        partial.replace(out)
    finally:
        partial.unlink(missing_ok=True)
    shown = ", ".join(f"{r:.1f}" for r in returns)
    click.echo(f"wrote {out} ({count} frames, {count / fps:.1f} s; returns {shown})")
