"""The CLI's error contract: a TacbenchError prints its message, no traceback, exit status 2."""

from __future__ import annotations

import click
import pytest
from click.testing import CliRunner

from tacbench import __version__
from tacbench.cli import cli
from tacbench.cli.common import Group
from tacbench.errors import TacbenchError

pytestmark = pytest.mark.unit


def test_user_error_exits_with_status_two_and_no_traceback() -> None:
    @click.group(cls=Group)
    def group() -> None:
        pass

    @group.command()
    def broken() -> None:
        raise TacbenchError("q must be > 0; pass --q 1.5 for example.")

    result = CliRunner().invoke(group, ["broken"])
    assert result.exit_code == 2
    assert "Error: q must be > 0; pass --q 1.5 for example." in result.output
    assert "Traceback" not in result.output


def test_other_exceptions_are_not_swallowed() -> None:
    @click.group(cls=Group)
    def group() -> None:
        pass

    @group.command()
    def bug() -> None:
        raise RuntimeError("a real bug")

    result = CliRunner().invoke(group, ["bug"])
    assert result.exit_code == 1
    assert isinstance(result.exception, RuntimeError)


def test_version() -> None:
    result = CliRunner().invoke(cli, ["--version"])
    assert result.exit_code == 0 and __version__ in result.output
