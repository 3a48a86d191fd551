"""Markdown and HTML rendering of the page model, and the CLI defaults."""

from __future__ import annotations

import base64
import inspect

import pandas as pd
import pytest
from click.testing import CliRunner

from tacbench.cli import cli
from tacbench.report import ReportOptions
from tacbench.report.render import (
    Bullets,
    Code,
    Image,
    Section,
    Table,
    Text,
    markdown_table,
    to_html,
    to_markdown,
)

pytestmark = pytest.mark.unit

PAGE = [
    Section(
        "Results",
        [
            Text("Use `--metric train` <here>."),
            Bullets(["one", "two & three"]),
            Table(pd.DataFrame({"a": ["x|y"], "b": [1.5]}), "caption"),
            Image("curves", "The curves."),
            Image("absent", "Not drawn."),
            Code("Commands", ["tacbench run --q 1.5", "echo '<b>'"]),
        ],
    )
]


def test_markdown_table_escapes_pipes() -> None:
    table = markdown_table(pd.DataFrame({"a": ["x|y", "z"], "b": [1, 2]}))
    assert table.splitlines() == ["| a | b |", "|---|---|", "| x\\|y | 1 |", "| z | 2 |"]


def test_markdown_page_links_figure_files() -> None:
    text = to_markdown("Title", PAGE, {"curves": "curves.png"})
    assert text.startswith("# Title\n\n## Results\n")
    assert "![The curves.](curves.png)" in text
    assert "Not drawn." not in text
    assert "```\ntacbench run --q 1.5\necho '<b>'\n```" in text
    assert "- two & three" in text


def test_html_page_is_self_contained_and_escaped() -> None:
    png = b"\x89PNG fake bytes"
    page = to_html("Title <1>", PAGE, {"curves": ("png", png)})
    uri = "data:image/png;base64," + base64.b64encode(png).decode()
    assert f'src="{uri}"' in page
    assert page.count("<img") == 1 and "http" not in page
    assert "<code>--metric train</code> &lt;here&gt;." in page
    assert "<td>x|y</td>" in page and "<caption>caption</caption>" in page
    assert "echo &#x27;&lt;b&gt;&#x27;" in page
    assert "<title>Title &lt;1&gt;</title>" in page


def test_cli_defaults_match_the_library_defaults() -> None:
    command = cli.commands["report"]
    defaults = {p.name: p.default for p in command.params}
    signature = inspect.signature(ReportOptions)
    for name in ("metric", "reps", "last", "grid_points"):
        assert defaults[name] == signature.parameters[name].default
    assert defaults["fmt"] == signature.parameters["fmt"].default
    help_text = CliRunner().invoke(cli, ["report", "--help"]).output
    assert "--reps" in help_text and "[default: 2000]" in help_text
