"""The report's document model and its two renderings.

A report is a list of sections made of paragraphs, tables, figures and preformatted text;
`render_html` makes one self-contained page of them (figures embedded as data URIs, inline CSS,
a Content-Security-Policy that forbids any request) and `render_markdown` its twin, whose
figures are PNG files under `<out_dir>/figures/`, so both always say the same.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from scanloc.evaluate.table2 import markdown_table

CSS = """
body{font:15px/1.5 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;color:#222;margin:0;
background:#fafafa}
main{max-width:1100px;margin:0 auto;padding:1em 1.5em 4em;background:#fff}
h1{font-size:1.6em;margin-bottom:.2em}h2{border-bottom:2px solid #ddd;padding-top:.8em}
nav a{margin-right:1em}table{border-collapse:collapse;margin:.8em 0;font-size:.86em;
display:block;overflow-x:auto;max-width:100%}
th,td{border:1px solid #ccc;padding:.25em .5em;text-align:left;vertical-align:top}
th{background:#f0f0f0}figure{margin:1em 0}img{max-width:100%;height:auto;box-sizing:border-box;
border:1px solid #eee}figcaption{font-size:.9em;color:#555}
pre{background:#f6f6f6;padding:.6em;overflow-x:auto;font-size:.82em}
.v-reproduced td{background:#d4edc9}.v-direction td{background:#fbefc4}
.v-not td{background:#f5d0d0}.v-untestable td{background:#e6e6e6}
.v-inconclusive td{background:#dbe6f4}
"""
CSP = "default-src 'none'; img-src data:; style-src 'unsafe-inline'"


# ---------------------------------------------------------------- document model


@dataclass(frozen=True)
class Para:
    text: str


@dataclass(frozen=True)
class Table:
    header: list[str]
    rows: list[list[str]]
    row_classes: list[str] | None = None


@dataclass(frozen=True)
class Figure:
    file: str  # file name under <out_dir>/figures/
    caption: str


@dataclass(frozen=True)
class Pre:
    summary: str
    text: str


@dataclass
class Section:
    id: str
    title: str
    blocks: list[Para | Table | Figure | Pre] = field(default_factory=list)


Block = Para | Table | Figure | Pre


class Builder:
    """Collects sections and writes each figure once, remembering its file name."""

    def __init__(self, root: Path, out_dir: Path, context: Mapping[str, Any]) -> None:
        self.root, self.out_dir, self.context = root, out_dir, context
        self.figure_dir = out_dir / "figures"
        self.written: list[str] = []

    def figure(self, name: str, caption: str, draw: Callable[[Path], object]) -> Figure:
        """Draw a figure into <out_dir>/figures/<name> and return its block."""
        draw(self.figure_dir / name)
        self.written.append(name)
        return Figure(name, caption)


def _png_size(data: bytes) -> tuple[int, int]:
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


def _html_block(block: Block, figure_dir: Path) -> str:
    esc = html.escape
    if isinstance(block, Para):
        return f"<p>{esc(block.text)}</p>"
    if isinstance(block, Pre):
        summary, text = esc(block.summary), esc(block.text)
        return f"<details><summary>{summary}</summary><pre>{text}</pre></details>"
    if isinstance(block, Figure):
        data = (figure_dir / block.file).read_bytes()
        width, height = _png_size(data)
        uri = "data:image/png;base64," + base64.b64encode(data).decode("ascii")
        return (
            f'<figure><img src="{uri}" alt="{esc(block.caption)}" width="{width}" '
            f'height="{height}"><figcaption>{esc(block.caption)}</figcaption></figure>'
        )
    head = "".join(f"<th>{esc(h)}</th>" for h in block.header)
    body = []
    for i, row in enumerate(block.rows):
        cls = f' class="{block.row_classes[i]}"' if block.row_classes else ""
        body.append(f"<tr{cls}>" + "".join(f"<td>{esc(c)}</td>" for c in row) + "</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _md_block(block: Block) -> str:
    if isinstance(block, Para):
        return block.text + "\n"
    if isinstance(block, Pre):
        return (
            f"<details><summary>{block.summary}</summary>\n\n```yaml\n{block.text}```\n</details>\n"
        )
    if isinstance(block, Figure):
        return f"![{_md_cell(block.caption)}](figures/{block.file})\n\n*{block.caption}*\n"
    rows = [[_md_cell(c) for c in row] for row in block.rows]
    return markdown_table([_md_cell(h) for h in block.header], rows)


def render_html(sections: list[Section], title: str, summary: str, figure_dir: Path) -> str:
    nav = " ".join(f'<a href="#{s.id}">{html.escape(s.title)}</a>' for s in sections)
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f'<meta http-equiv="Content-Security-Policy" content="{CSP}">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{html.escape(title)}</title><style>{CSS}</style></head>",
        f"<body><main><h1>{html.escape(title)}</h1><p>{html.escape(summary)}</p><nav>{nav}</nav>",
    ]
    for section in sections:
        parts.append(f'<section><h2 id="{section.id}">{html.escape(section.title)}</h2>')
        parts += [_html_block(block, figure_dir) for block in section.blocks]
        parts.append("</section>")
    parts.append("</main></body></html>")
    return "\n".join(parts) + "\n"


def render_markdown(sections: list[Section], title: str, summary: str) -> str:
    parts = [f"# {title}\n", summary + "\n"]
    for section in sections:
        parts.append(f'<h2 id="{section.id}">{section.title}</h2>\n')
        parts += [_md_block(block) for block in section.blocks]
    return "\n".join(parts)
