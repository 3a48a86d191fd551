"""The settings' declarations (tacbench/config.py) against what users read: ``tacbench run
--help`` and the config table of docs/results-schema.md."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

from tacbench import paper
from tacbench.cli import cli
from tacbench.config import RunConfig
from tacbench.settings import settings_of

pytestmark = pytest.mark.unit

SCHEMA = Path(__file__).resolve().parents[1] / "docs" / "results-schema.md"


def test_run_help_shows_every_default_and_none_is_none() -> None:
    result = CliRunner().invoke(cli, ["run", "--help"], terminal_width=200)
    assert result.exit_code == 0
    text = " ".join(result.output.split())
    assert "default: None" not in text
    assert "[default: paper: 300; reference, authors-*: 400,300" in text
    assert "[default: paper: step; reference, authors-*: episode" in text
    assert "[default: -A ln_q(e) (--lnq per-dim) or -ln_q(e^A) (joint)" in text
    assert not re.search(r"\bissue \d+", text)


def _config_table() -> dict[str, list[str]]:
    text = SCHEMA.read_text()
    section = text[text.index("### `config`: every RunConfig field") :]
    table = section[section.index("| field |") :]
    rows = {}
    for line in table.splitlines()[2:]:
        if not line.startswith("| `"):
            break
        cells = [cell.strip() for cell in line.strip("|").split(" | ")]
        rows[cells[0].strip("`")] = cells[1:]
    return rows


def _shown(value: object) -> str:
    return json.dumps(list(value) if isinstance(value, tuple) else value)


def test_the_schema_table_lists_every_field_with_its_declared_default() -> None:
    rows = _config_table()
    assert set(rows) == {f.name for f in dataclasses.fields(RunConfig)}
    for name, declared in settings_of(RunConfig).items():
        default = rows[name][0]
        if declared.info.profile:
            for profile, values in paper.PROFILES.items():
                assert _shown(values[name]) in default, (name, profile, default)
        else:
            assert _shown(declared.default) in default, (name, default)
