"""Checkpoint generations (``tacbench.runs.checkpoints``) on real files: manifests, pruning to two,
choosing what a group resumes from, forgetting later generations, disk errors as messages."""

from __future__ import annotations

import errno
import hashlib
import json
from pathlib import Path

import pytest

from tacbench.errors import TacbenchError
from tacbench.runs import checkpoints
from tacbench.runs.checkpoints import DiskError


def _generation(folder: Path, step: int, *shared: str) -> None:
    """A generation at ``step``: its own state file and the ``shared`` files (written once)."""
    files = []
    for name in (f"state-{step}.bin", *shared):
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if not path.exists():
            checkpoints.write_durably(path, lambda h, n=name: h.write(f"{n}@{step}".encode()))
        files.append(path)
    checkpoints.commit(folder, step, files)


def test_commit_records_sizes_and_checksums_and_keeps_two_generations(tmp_path: Path) -> None:
    for step in (100, 200, 300):
        _generation(tmp_path, step, "replay/a.npz", f"replay/{step}.npz")
    (tmp_path / "leftover.tmp").write_bytes(b"half")
    _generation(tmp_path, 400, "replay/a.npz")
    names = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file())
    assert names == [
        "manifest-000000000300.json",
        "manifest-000000000400.json",
        "replay/300.npz",
        "replay/a.npz",
        "state-300.bin",
        "state-400.bin",
    ]
    manifest = json.loads((tmp_path / "manifest-000000000400.json").read_text())
    assert manifest["step"] == 400
    written = b"state-400.bin@400"  # checked against its own hash, not the function that wrote it
    expected = {"size": len(written), "sha256": hashlib.sha256(written).hexdigest()}
    assert manifest["files"]["state-400.bin"] == expected
    assert set(manifest["files"]) == {"state-400.bin", "replay/a.npz"}
    assert checkpoints.usable_steps(tmp_path) == ([400, 300], {})


def test_problems_name_the_damaged_file(tmp_path: Path) -> None:
    _generation(tmp_path, 100, "chunk")
    (tmp_path / "chunk").write_bytes(b"chunk@101")  # same size, other bytes
    (tmp_path / "state-100.bin").write_bytes(b"x")
    assert checkpoints.problems(tmp_path, 100) == [
        "state-100.bin: 1 bytes, 17 recorded",
        "chunk: its checksum does not match the manifest's",
    ]
    (tmp_path / "chunk").unlink()
    assert "chunk: missing" in checkpoints.problems(tmp_path, 100)
    big = tmp_path / "big.bin"  # more than one block of the checksum: damage at its end counts
    checkpoints.write_durably(big, lambda h: h.write(bytes(3 << 20)))
    checkpoints.commit(tmp_path, 200, [big])
    with big.open("r+b") as handle:
        handle.seek((3 << 20) - 1)
        handle.write(b"\x01")
    assert checkpoints.problems(tmp_path, 200) == [
        "big.bin: its checksum does not match the manifest's"
    ]
    (tmp_path / "manifest-000000000100.json").write_text("{")
    assert checkpoints.problems(tmp_path, 100) == [
        "manifest-000000000100.json: unreadable (JSONDecodeError)"
    ]


@pytest.mark.parametrize(
    ("manifest", "error"),
    [
        ("null", "TypeError"),
        ('{"files": []}', "AttributeError"),
        ('{"files": {"state-100.bin": {"size": "big"}}}', "ValueError"),
        ('{"files": {}, "logs": {"eval.csv": {"rows": 3}}}', "KeyError"),
    ],
)
def test_a_manifest_that_parses_but_is_damaged_is_unreadable(
    tmp_path: Path, manifest: str, error: str
) -> None:
    """Not only a torn file: a manifest of the wrong shape is a damaged generation, which a
    resume passes over (it ended in a traceback)."""
    _generation(tmp_path, 100)
    _generation(tmp_path, 200)
    (tmp_path / "manifest-000000000200.json").write_text(manifest)
    assert checkpoints.problems(tmp_path, 200) == [
        f"manifest-000000000200.json: unreadable ({error})"
    ]
    assert checkpoints.usable_steps(tmp_path)[0] == [100]


def test_a_group_resumes_from_the_newest_step_all_its_members_have(tmp_path: Path) -> None:
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    for folder in (a, b):
        _generation(folder, 100)
    _generation(a, 200)  # a crash between the members' checkpoints at 200
    assert checkpoints.choose([a, b]) == (100, [])
    c.mkdir()
    assert checkpoints.choose([c]) == (None, [])  # no checkpoint: start afresh
    d = tmp_path / "d"
    _generation(d, 300)
    with pytest.raises(TacbenchError, match="the members' checkpoints are at different steps"):
        checkpoints.choose([a, d])
    # every checkpoint intact (members resumed apart): not --force, which deletes them all
    apart = [tmp_path / "q1-a0.2" / seed / "checkpoint" for seed in ("seed0", "seed1")]
    for step in (100, 200):
        _generation(apart[0], step)
    _generation(apart[1], 300)
    with pytest.raises(TacbenchError) as refused:
        checkpoints.choose(apart)
    assert "(q1-a0.2/seed0 at 100, 200; q1-a0.2/seed1 at 300)" in str(refused.value)
    assert "resume each member in a command of its own" in str(refused.value)
    # a new member beside a partial one: the advice was --force, which would lose a's steps
    with pytest.raises(TacbenchError) as refused:
        checkpoints.choose([a, c / "checkpoint"])
    assert f"{c} has no checkpoint, and the other members have" in str(refused.value)
    assert "--force" not in str(refused.value)
    assert "resume the others in a command without the new members" in str(refused.value)
    # when the others could not resume either (their checkpoint damaged), that is what it says
    damaged = tmp_path / "e"
    _generation(damaged, 100)
    (damaged / "state-100.bin").write_bytes(b"")
    with pytest.raises(TacbenchError) as refused:
        checkpoints.choose([damaged, c / "checkpoint"])
    assert f"{damaged}: the checkpoint at step 100 is damaged" in str(refused.value)
    assert "resume the others" not in str(refused.value)


def test_a_first_checkpoint_cut_short_between_members_starts_the_group_afresh(
    tmp_path: Path,
) -> None:
    """A member without a checkpoint that trained in the group from its start (its config.json
    lists the same members) beside members holding only the first generation: the group was
    stopped while it committed its first checkpoint, so it starts afresh. A member the others
    do not list, or others with two generations, are refused as before."""
    group = {"members": [{"q": 2.0, "alpha": 0.2, "seed": 0}, {"q": 2.0, "alpha": 0.2, "seed": 1}]}
    runs = [tmp_path / "seed0", tmp_path / "seed1"]
    for run in runs:
        (run / "checkpoint").mkdir(parents=True)
        (run / "config.json").write_text(json.dumps(group))
    _generation(runs[0] / "checkpoint", 100)
    folders = [run / "checkpoint" for run in runs]
    step, [note] = checkpoints.choose(folders)
    assert step is None
    assert note.startswith("the group's first checkpoint (step 100) was cut short before")
    (runs[1] / "config.json").write_text(json.dumps({"members": group["members"][1:]}))
    with pytest.raises(TacbenchError, match="has no checkpoint, and the other members have"):
        checkpoints.choose(folders)
    (runs[1] / "config.json").write_text("[1, 2]")  # not an object: not of the group either
    with pytest.raises(TacbenchError, match="has no checkpoint, and the other members have"):
        checkpoints.choose(folders)
    (runs[1] / "config.json").write_text(json.dumps(group))
    _generation(runs[0] / "checkpoint", 200)  # its second: the group did checkpoint once
    with pytest.raises(TacbenchError, match="has no checkpoint, and the other members have"):
        checkpoints.choose(folders)


def test_a_damaged_generation_is_passed_over_and_later_ones_forgotten(tmp_path: Path) -> None:
    for step in (100, 200):
        _generation(tmp_path, step)
    (tmp_path / "state-200.bin").write_bytes(b"")
    step, notes = checkpoints.choose([tmp_path])
    assert step == 100
    assert notes == [
        f"{tmp_path}: the checkpoint at step 200 is damaged (state-200.bin: 0 bytes, 17 recorded)"
    ]
    checkpoints.discard_after(tmp_path, 100)
    assert checkpoints.usable_steps(tmp_path) == ([100], {})


def test_no_usable_generation_is_an_error_and_nothing_is_deleted(tmp_path: Path) -> None:
    for step in (100, 200):
        _generation(tmp_path, step, "shared")
    (tmp_path / "shared").write_bytes(b"SHARED@100")
    before = sorted(tmp_path.rglob("*"))
    with pytest.raises(TacbenchError, match=r"no usable checkpoint.*shared: its checksum") as err:
        checkpoints.choose([tmp_path])
    assert str(err.value).endswith(
        "Nothing was deleted; rerun with --force to start the run over (tacbench sweep: delete "
        "the run's directory)."
    )
    assert sorted(tmp_path.rglob("*")) == before


def test_a_checkpoint_from_before_manifests_is_refused(tmp_path: Path) -> None:
    (tmp_path / "state.pt").write_bytes(b"old")
    with pytest.raises(TacbenchError, match="written by an older tacbench"):
        checkpoints.choose([tmp_path])


def test_a_failed_write_leaves_neither_a_temporary_nor_a_change(tmp_path: Path) -> None:
    path = tmp_path / "state.bin"
    checkpoints.write_durably(path, lambda handle: handle.write(b"old"))

    def fails(handle: object) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    with pytest.raises(OSError) as err:
        checkpoints.write_durably(path, fails)
    assert err.value.filename == str(path)
    assert path.read_bytes() == b"old" and not list(tmp_path.glob("*.tmp"))


@pytest.mark.parametrize(
    ("code", "full", "says"),
    [
        (errno.ENOSPC, True, "the disk is full; free some space, then rerun with --resume"),
        (errno.EROFS, False, "read-only file system; choose a folder you can write with --out"),
    ],
)
def test_disk_errors_become_one_clear_message(code: int, full: bool, says: str) -> None:
    with pytest.raises(DiskError) as err, checkpoints.disk_errors("the run's files"):
        raise OSError(code, "os message", "/out/eval.csv")
    assert err.value.full is full
    assert str(err.value).startswith(f"cannot write the run's files (/out/eval.csv): {says}")
    with pytest.raises(FileNotFoundError), checkpoints.disk_errors("the run's files"):
        raise FileNotFoundError(errno.ENOENT, "not a disk error")
