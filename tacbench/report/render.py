"""A tiny document model rendered to Markdown and to one self-contained HTML page.

A page is a list of :class:`Section`; each holds blocks: :class:`Text` (with ``code`` spans),
:class:`Bullets`, :class:`Table` (a DataFrame), :class:`Image` (a figure by name) and
:class:`Code` (preformatted lines, folded away in HTML). Markdown links the figure files; HTML
embeds them as data URIs so ``index.html`` can be mailed or archived on its own.
"""

from __future__ import annotations

import base64
import html
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import pandas as pd


@dataclass(frozen=True)
class Text:
    """A paragraph; backticks mark code."""

    text: str


@dataclass(frozen=True)
class Bullets:
    """A bulleted list; backticks mark code."""

    items: Sequence[str]


@dataclass(frozen=True)
class Table:
    """A table of already formatted cells."""

    frame: pd.DataFrame
    caption: str = ""


@dataclass(frozen=True)
class Image:
    """A figure, by the stem of its file."""

    name: str
    caption: str


@dataclass(frozen=True)
class Code:
    """Preformatted lines, shown folded under ``summary`` in HTML."""

    summary: str
    lines: Sequence[str]


Block = Text | Bullets | Table | Image | Code


@dataclass(frozen=True)
class Section:
    """A titled part of the page."""

    title: str
    blocks: Sequence[Block]


def _md_cell(value: object) -> str:
    return str(value).replace("|", "\\|").replace("\n", " ")


def markdown_table(frame: pd.DataFrame) -> str:
    """A GitHub-flavoured Markdown table of ``frame`` (cells as ``str``)."""
    header = "| " + " | ".join(_md_cell(c) for c in frame.columns) + " |"
    rule = "|" + "|".join("---" for _ in frame.columns) + "|"
    body = ["| " + " | ".join(_md_cell(v) for v in row) + " |" for row in frame.itertuples(False)]
    return "\n".join([header, rule, *body])


def to_markdown(title: str, sections: Sequence[Section], files: Mapping[str, str]) -> str:
    """The page as Markdown; ``files`` maps figure names to their relative paths."""
    out = [f"# {title}", ""]
    for section in sections:
        out += [f"## {section.title}", ""]
        for block in section.blocks:
            if isinstance(block, Text):
                out += [block.text, ""]
            elif isinstance(block, Bullets):
                out += [*(f"- {item}" for item in block.items), ""]
            elif isinstance(block, Table):
                out += ([f"*{block.caption}*", ""] if block.caption else []) + [
                    markdown_table(block.frame),
                    "",
                ]
            elif isinstance(block, Image):
                if block.name in files:
                    out += [f"![{block.caption}]({files[block.name]})", "", block.caption, ""]
            else:
                out += [f"{block.summary}:", "", "```", *block.lines, "```", ""]
    return "\n".join(out)


def _inline(text: str) -> str:
    """Escape text for HTML and turn backtick spans into <code>."""
    return re.sub(r"`([^`]*)`", r"<code>\1</code>", html.escape(text, quote=False))


def _html_table(block: Table) -> str:
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in block.frame.columns)
    rows = "".join(
        "<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in row) + "</tr>"
        for row in block.frame.itertuples(False)
    )
    caption = f"<caption>{_inline(block.caption)}</caption>" if block.caption else ""
    return f"<table>{caption}<thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>"


_MIME = {"png": "image/png", "svg": "image/svg+xml"}

_STYLE = """
body { font-family: system-ui, sans-serif; max-width: 1300px; margin: 2em auto; padding: 0 1em;
       color: #222; line-height: 1.45; }
h1 { font-size: 1.6em; } h2 { border-bottom: 1px solid #ccc; padding-bottom: .2em; }
table { border-collapse: collapse; margin: .8em 0; font-size: .88em; }
caption { text-align: left; font-style: italic; padding-bottom: .3em; }
th, td { border: 1px solid #ccc; padding: .25em .55em; text-align: left; vertical-align: top; }
th { background: #f2f2f2; } tr:nth-child(even) td { background: #fafafa; }
figure { margin: 1em 0; } figure img { max-width: 100%; }
figcaption { font-size: .9em; color: #444; }
code { background: #f2f2f2; padding: 0 .2em; }
pre { background: #f7f7f7; padding: .6em; overflow-x: auto; font-size: .85em; }
"""


def to_html(
    title: str, sections: Sequence[Section], images: Mapping[str, tuple[str, bytes]]
) -> str:
    """The page as one HTML document; ``images`` maps figure names to (format, bytes)."""
    body = [f"<h1>{html.escape(title)}</h1>"]
    for section in sections:
        body.append(f"<h2>{html.escape(section.title)}</h2>")
        for block in section.blocks:
            if isinstance(block, Text):
                body.append(f"<p>{_inline(block.text)}</p>")
            elif isinstance(block, Bullets):
                items = "".join(f"<li>{_inline(item)}</li>" for item in block.items)
                body.append(f"<ul>{items}</ul>")
            elif isinstance(block, Table):
                body.append(_html_table(block))
            elif isinstance(block, Image):
                if block.name in images:
                    kind, data = images[block.name]
                    uri = f"data:{_MIME[kind]};base64,{base64.b64encode(data).decode('ascii')}"
                    body.append(
                        f'<figure><img alt="{html.escape(block.caption)}" src="{uri}">'
                        f"<figcaption>{_inline(block.caption)}</figcaption></figure>"
                    )
            else:
                lines = html.escape("\n".join(block.lines))
                body.append(
                    f"<details><summary>{_inline(block.summary)}</summary><pre>{lines}</pre>"
                    "</details>"
                )
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head>"
        f"<body>{''.join(body)}</body></html>\n"
    )
