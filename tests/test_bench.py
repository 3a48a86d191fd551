"""``tacbench bench``: the contestants, the table and its ratios, option checks, and one tiny
end-to-end run through the CLI (a few steps of Pendulum; no timing is asserted)."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from tacbench.bench import (
    BenchOptions,
    BenchResult,
    Contestant,
    contestants,
    phase_table,
    table,
)
from tacbench.cli import cli
from tacbench.errors import TacbenchError
from tacbench.hardware import bf16_instructions
from tacbench.update_profile import ELEMENTWISE

pytestmark = pytest.mark.unit


def test_contestants_cover_both_paths_at_one_and_k_members() -> None:
    rows = [(c.name, c.members) for c in contestants(BenchOptions(members=4, compile=True))]
    assert rows == [
        ("SB3 SAC", 1),
        ("TAC", 1),
        ("TAC compiled", 1),
        ("TAC", 4),
        ("TAC compiled", 4),
    ]
    options = BenchOptions(members=1, sb3=False, eager=False, compile=True)
    assert [c.name for c in contestants(options)] == ["TAC compiled"]
    options = BenchOptions(members=2, sb3=False, eager=False, compile=True, bf16=True)
    assert [(c.name, c.members, c.bf16) for c in contestants(options)] == [
        ("TAC compiled", 1, False),
        ("TAC compiled bf16", 1, True),
        ("TAC compiled", 2, False),
        ("TAC compiled bf16", 2, True),
    ]
    # the grid row is a TAC row too: --bf16 repeats it (it was left in float32 alone)
    options = BenchOptions(members=1, sb3=False, eager=False, grid=True, bf16=True)
    assert [(c.name, c.members, c.bf16) for c in contestants(options)] == [
        ("TAC q grid compiled", 90, False),
        ("TAC q grid compiled bf16", 90, True),
    ]


def test_table_reports_rates_member_rates_and_ratios_to_sb3() -> None:
    sb3 = BenchResult(Contestant("SB3 SAC", 1), steps=[100, 100], seconds=[1.0, 1.0])
    tac = BenchResult(Contestant("TAC", 10, tac=True), steps=[50, 50], seconds=[0.5, 0.25])
    assert tac.rate == pytest.approx(100 / 0.75)
    assert tac.member_rate == pytest.approx(1000 / 0.75)
    assert tac.spread == pytest.approx((100.0, 200.0))
    lines = table([sb3, tac]).splitlines()
    assert lines[2] == "| SB3 SAC | 1 | 100 | 100 | 1.00x | 100-100 |"
    assert lines[3] == "| TAC | 10 | 133 | 1333 | 13.33x | 100-200 |"


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"rounds": 0}, "--rounds"),
        ({"steps": 2, "rounds": 3}, "--steps"),
        ({"members": 0}, "--members"),
    ],
)
def test_bench_options_are_checked(options: dict[str, int], message: str) -> None:
    with pytest.raises(TacbenchError, match=message):
        BenchOptions(**options)  # type: ignore[arg-type]


def test_bench_command_runs_every_contestant_and_writes_json(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    scratch = tmp_path / "tmp"  # the temporary folder: SB3 used to leave a folder per learn()
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    out = tmp_path / "new" / "bench.json"  # its folder is made
    args = ["bench", "--env", "Pendulum-v1", "--members", "2", "--steps", "4", "--rounds", "2"]
    result = CliRunner().invoke(cli, [*args, "--learning-starts", "3", "--json", str(out)])
    assert result.exit_code == 0, result.output
    assert not list(scratch.glob("SB3-*"))
    assert "| SB3 SAC | 1 |" in result.output and "| TAC | 2 |" in result.output
    record = json.loads(out.read_text())
    assert [(r["name"], r["members"]) for r in record["results"]] == [
        ("SB3 SAC", 1),
        ("TAC", 1),
        ("TAC", 2),
    ]
    assert all(r["steps"] == [2, 2] and len(r["seconds"]) == 2 for r in record["results"])
    assert record["machine"]["at start"]["cores"] == record["machine"]["at end"]["cores"] >= 1
    assert record["options"]["networks"] == [300]  # the paper's, which hidden_sizes None means
    # TAC's rows split their time into the training loop's phases; SB3's has none
    sb3, *tacs = record["results"]
    assert sb3["phase_seconds"] == {}
    for row in tacs:
        assert set(row["phase_seconds"]) == {"act", "environments", "sample", "update"}
        assert 0 < sum(row["phase_seconds"].values()) <= sum(row["seconds"])
    assert "| learner | members | ms/step | act | environments | sample | update | rest |" in (
        result.output
    )


def test_phase_table_gives_each_phases_share_and_the_rest() -> None:
    phases = {"act": 0.1, "environments": 0.3, "sample": 0.05, "update": 0.5}
    tac = BenchResult(Contestant("TAC", 2, tac=True), [50, 50], [0.5, 0.5], phases)
    sb3 = BenchResult(Contestant("SB3 SAC", 1), [100], [1.0])
    assert tac.phase_shares == pytest.approx({**phases, "rest": 0.05})
    assert sb3.phase_shares == {}
    lines = phase_table([sb3, tac]).splitlines()
    assert lines[-1] == "| TAC | 2 | 10.00 | 10% | 30% | 5% | 50% | 5% |"
    assert phase_table([sb3]) == ""


def test_bench_command_refuses_bad_options(tmp_path: Path) -> None:
    result = CliRunner().invoke(cli, ["bench", "--steps", "1", "--rounds", "3"])
    assert result.exit_code == 2
    assert "--steps must be at least --rounds" in result.output
    result = CliRunner().invoke(cli, ["bench", "--steps", "7", "--rounds", "5"])  # timed 5 of 7
    assert result.exit_code == 2 and "give a multiple of --rounds, --steps 5" in result.output
    result = CliRunner().invoke(cli, ["bench", "--no-sb3", "--no-eager"])
    assert result.exit_code == 2 and "leave nothing to measure" in result.output
    (tmp_path / "afile").write_text("")  # --json below a file: refused before measuring
    json_path = str(tmp_path / "afile" / "bench.json")
    result = CliRunner().invoke(cli, ["bench", "--env", "Pendulum-v1", "--json", json_path])
    assert result.exit_code == 2 and "choose one you can write with --json" in result.output
    assert "SB3 SAC" not in result.output


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (  # --profile measured one update on one thread whatever these said
            ["--profile", "--grid", "--threads", "2", "--rounds", "3"],
            "--profile measures one update on one thread, not the race: leave out --rounds, "
            "--grid, --threads.",
        ),
        (["--no-compile-profile"], "--no-compile-profile applies with --profile only"),
        (["--bf16", "--no-eager"], "--no-eager without --compile or --grid leaves no TAC row"),
        (["--threads", "1000"], "--threads 1000 is more than this machine's"),
        (["--hidden-sizes", "100000,100000"], "this run would need about"),
        (  # advised leaving out a --grid that was not given
            ["--members", "100000", "--hidden-sizes", "3000"],
            "make --hidden-sizes or --members smaller",
        ),
        (["--json", ""], "--json must name a file, not a folder (got '')"),
        (["--json", "newdir/"], "got 'newdir/'); for example --json newdir/bench.json."),
    ],
)
def test_bench_refuses_what_it_would_ignore_or_could_not_run(args: list[str], message: str) -> None:
    """Each used to be ignored, or to fail with a traceback once measuring had begun."""
    result = CliRunner().invoke(cli, ["bench", "--env", "Pendulum-v1", *args])
    assert result.exit_code == 2, result.output
    assert message in result.output and "Traceback" not in result.output


def test_hidden_sizes_reach_tac_and_sb3_and_bad_widths_are_refused(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import stable_baselines3

    from tacbench.bench import _network_overrides, _sb3_sac, _tac_configs

    options = BenchOptions(env="Pendulum-v1", members=2, hidden_sizes=(16, 8))
    assert _network_overrides(options) == {"hidden_sizes": (16, 8)}
    configs = _tac_configs(options, Contestant("TAC", 2, tac=True))
    assert [c.hidden_sizes for c in configs] == [(16, 8), (16, 8)]
    built: dict[str, Any] = {}  # what SB3's SAC is built with, without training it

    class _Built:
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            built.update(kwargs)

        def set_logger(self, logger: Any) -> None:
            built["logger"] = logger

    monkeypatch.setattr(stable_baselines3, "SAC", _Built)
    with _sb3_sac(options):
        assert built["policy_kwargs"] == {"net_arch": [16, 8]}
    assert _network_overrides(BenchOptions()) == {}  # the paper's networks
    with pytest.raises(TacbenchError, match="--hidden-sizes 400,300"):
        BenchOptions(hidden_sizes=(300, 0))


def test_bench_profile_splits_an_update_into_products_and_the_rest(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from tacbench import update_profile

    monkeypatch.setattr(update_profile, "PROFILED_UPDATES", 3)  # a profile, not a measurement
    monkeypatch.setattr(update_profile, "PEAK_SIZE", 256)
    configured: list[int] = []
    monkeypatch.setattr(update_profile, "configure_process", configured.append)
    out = tmp_path / "profile.json"
    args = ["bench", "--profile", "--no-compile-profile", "--env", "Pendulum-v1"]
    args += ["--members", "2", "--hidden-sizes", "16,8", "--json", str(out)]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert "| where | calls/update |" in result.output
    record = json.loads(out.read_text())
    assert set(record["machine"]) == {"at start", "at end"}  # as the race's JSON
    profiles = record["profiles"]
    assert [p["members"] for p in profiles] == [1, 2]
    assert configured == [1, 1]  # one thread and the flush of subnormals, as training runs
    for profile in profiles:
        rows = {r["what"]: r for r in profile["rows"]}
        # Pendulum (3 observations, 1 action): the policy's first layer, 3 -> 16 for a batch of
        # 100, is a baddbmm of (K, 100, 3) @ (K, 3, 16) in the eager update
        k = profile["members"]
        first = rows[f"product {k}x100x3 @ {k}x3x16"]
        assert first["calls"] >= 1 and first["gflops"] > 0
        assert rows["Adam"]["calls"] == 1
        assert ELEMENTWISE not in rows  # eager: its elementwise ops are in the rest, said so
        # the named rows' times fit inside the profiled update (the rest, the update's time that
        # no row names, is the difference, so it must not be negative), and all rows add up to it
        *named, rest = profile["rows"]
        assert rest["what"] == "the rest (elementwise ops, Python, dispatch)"
        assert rest["us"] >= 0
        assert all(r["us"] > 0 if r["calls"] else r["us"] == 0 for r in named)
        total = sum(r["us"] for r in profile["rows"])
        assert total == pytest.approx(profile["profiled_update_us"], rel=1e-6)
        assert profile["peak_gflops"] > 0


@pytest.mark.parametrize(
    ("kernel", "kind"),
    [
        ("sm90_xmma_gemm_f32f32_tf32f32_f32_tn_n_tilesize128x128x32", "matrix products"),
        ("void cutlass::Kernel2<cutlass_80_simt_sgemm_128x64_8x5_nn_align1>", "matrix products"),
        ("triton_poi_fused_add_mul_0", "elementwise (compiled kernels)"),
        ("void at::native::(anonymous namespace)::multi_tensor_apply_kernel<FusedAdam>", "Adam"),
        ("Memcpy HtoD (Pageable -> Device)", "copies"),
        ("void at::native::reduce_kernel<512, 1>", "other kernels"),
    ],
)
def test_gpu_kernels_are_sorted_by_what_they_do(kernel: str, kind: str) -> None:
    from tacbench.update_profile import _kernel_kind

    assert _kernel_kind(kernel) == kind


def test_product_flops_counts_two_per_multiply_add() -> None:
    from tacbench.update_profile import _product_flops

    assert _product_flops([[5, 100, 400], [5, 400, 300]]) == 2 * 5 * 100 * 400 * 300


@pytest.mark.skipif(not bf16_instructions(), reason="this CPU has no native bfloat16 instructions")
def test_bench_profile_of_the_bf16_update_counts_its_bfloat16_products(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from tacbench import update_profile

    monkeypatch.setattr(update_profile, "PROFILED_UPDATES", 3)
    monkeypatch.setattr(update_profile, "PEAK_SIZE", 256)
    out = tmp_path / "profile.json"
    args = ["bench", "--profile", "--bf16", "--no-compile-profile", "--env", "Pendulum-v1"]
    args += ["--members", "1", "--hidden-sizes", "16,8", "--json", str(out)]
    result = CliRunner().invoke(cli, args)
    assert result.exit_code == 0, result.output
    assert "bf16 products" in result.output
    (profile,) = json.loads(out.read_text())["profiles"]
    assert profile["matmul_precision"] == "bf16"
    rows = {r["what"]: r for r in profile["rows"]}
    assert rows["product 1x100x3 @ 1x3x16"]["calls"] >= 1  # a bmm of the rounded inputs


def test_the_size_check_counts_the_replay_rows_the_bench_fills(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The 90-member grid reserves a million rows per member but fills a few thousand: on a
    4 GiB machine it fits (the check used to count the reserve, about 10 GiB), and a refusal
    names bench's own flags."""
    from tacbench import bench, memory

    monkeypatch.setattr(memory, "machine_memory", lambda: 4 << 30)
    bench.check_sizes(BenchOptions(env="HalfCheetah-v4", grid=True, compile=True, eager=False))
    with pytest.raises(TacbenchError, match=r"make --hidden-sizes or --members smaller"):
        bench.check_sizes(BenchOptions(env="HalfCheetah-v4", hidden_sizes=(20_000, 20_000)))
    grid = BenchOptions(env="HalfCheetah-v4", hidden_sizes=(20_000, 20_000), grid=True)
    with pytest.raises(TacbenchError, match=r"make --hidden-sizes or --members \(or leave out"):
        bench.check_sizes(grid)


def test_the_size_check_counts_every_member_of_the_largest_group(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Every member of the largest TAC row is sized: the grid's 90, --members' own count; one
    config stands for them all (building 100,000 of them delayed the refusal by 20 s)."""
    from tacbench import bench, memory

    measured: list[dict[str, int]] = []
    monkeypatch.setattr(memory, "check_fits", lambda needs, *_: measured.append(dict(needs)))
    for options in (
        BenchOptions(env="HalfCheetah-v4", members=1),
        BenchOptions(env="HalfCheetah-v4", members=1, grid=True, compile=True, eager=False),
        BenchOptions(env="HalfCheetah-v4", members=100_000),
    ):
        bench.check_sizes(options)
    one, grid, many = measured
    assert grid == {part: 90 * size for part, size in one.items()}
    assert many["networks"] == 100_000 * one["networks"]
