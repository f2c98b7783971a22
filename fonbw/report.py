"""Markdown and self-contained HTML reports built from sections.

A section has a title, one line saying what it shows, optional Markdown body
(tables, lists) and optional PNG figures. The HTML embeds every figure as a
data URI so the file can be mailed or opened anywhere; it also marks, once
the page has loaded, how many images decoded (``data-images-ok`` on <body>),
which the browser check of the tests reads.
"""
from __future__ import annotations

import base64
import dataclasses
import html
import os
import re

from .io import atomic_open

__all__ = ["Section", "write_markdown", "write_html", "md_table"]


@dataclasses.dataclass
class Section:
    title: str
    caption: str
    body: str = ""
    figures: list = dataclasses.field(default_factory=list)  # [(path, caption)]


def md_table(header, rows) -> str:
    """A Markdown table from a header and rows of cells (floats formatted to 4 significant digits)."""
    fmt = lambda v: f"{v:.4g}" if isinstance(v, float) else str(v)
    out = ["| " + " | ".join(map(str, header)) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(fmt(v) for v in r) + " |" for r in rows]
    return "\n".join(out)


def write_markdown(path, title, sections, intro="") -> None:
    """Markdown report; figures are linked relative to the report's folder."""
    base = os.path.dirname(os.path.abspath(path))
    lines = [f"# {title}", ""]
    if intro:
        lines += [intro, ""]
    for s in sections:
        lines += [f"## {s.title}", "", f"*{s.caption}*", ""]
        if s.body:
            lines += [s.body, ""]
        for p, cap in s.figures:
            lines += [f"![{cap}]({os.path.relpath(p, base)})", "", f"{cap}", ""]
    with atomic_open(path, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines))


def _md_to_html(md: str) -> str:
    """The small Markdown subset the reports use: tables, bullets, bold, code, paragraphs."""
    out, table, bullets = [], [], []

    def inline(s):
        s = html.escape(s)
        s = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", s)
        s = re.sub(r"`(.+?)`", r"<code>\1</code>", s)
        return s

    def flush():
        if table:
            rows = [r for r in table if not re.fullmatch(r"\|?(\s*-+\s*\|)+\s*-*\s*", r)]
            cells = [[c.strip() for c in r.strip().strip("|").split("|")] for r in rows]
            h = "".join(f"<th>{inline(c)}</th>" for c in cells[0])
            b = "".join("<tr>" + "".join(f"<td>{inline(c)}</td>" for c in r) + "</tr>" for r in cells[1:])
            out.append(f"<table><thead><tr>{h}</tr></thead><tbody>{b}</tbody></table>")
            table.clear()
        if bullets:
            out.append("<ul>" + "".join(f"<li>{inline(b)}</li>" for b in bullets) + "</ul>")
            bullets.clear()

    for line in md.splitlines():
        if line.startswith("|"):
            table.append(line)
            continue
        if line.startswith("- "):
            bullets.append(line[2:])
            continue
        flush()
        if line.startswith("### "):
            out.append(f"<h3>{inline(line[4:])}</h3>")
        elif line.strip():
            out.append(f"<p>{inline(line)}</p>")
    flush()
    return "\n".join(out)


_CSS = """body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:.8em 0}td,th{border:1px solid #bbb;padding:.25em .6em;text-align:right}
th{background:#eee}td:first-child,th:first-child{text-align:left}img{max-width:100%;border:1px solid #ddd}
.cap{font-style:italic;color:#555}figure{margin:1em 0}figcaption{color:#555;font-size:.9em}
nav a{margin-right:1em}code{background:#f4f4f4;padding:0 .2em}"""

_ONLOAD = """<script>
window.addEventListener('load', function () {
  var im = document.images, ok = 0;
  for (var i = 0; i < im.length; i++) { if (im[i].complete && im[i].naturalWidth > 0) ok++; }
  document.body.setAttribute('data-images-ok', ok + '/' + im.length);
});
</script>"""


def write_html(path, title, sections, intro="") -> None:
    """Self-contained HTML report (figures embedded as base64 PNG)."""
    anchors = [re.sub(r"[^a-z0-9]+", "-", s.title.lower()).strip("-") for s in sections]
    parts = [f"<!doctype html><html lang='en'><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
             f"<style>{_CSS}</style>{_ONLOAD}</head><body>", f"<h1>{html.escape(title)}</h1>"]
    if intro:
        parts.append(_md_to_html(intro))
    parts.append("<nav>" + "".join(f"<a href='#{a}'>{html.escape(s.title)}</a>" for a, s in zip(anchors, sections))
                 + "</nav>")
    for a, s in zip(anchors, sections):
        parts.append(f"<section id='{a}'><h2>{html.escape(s.title)}</h2><p class='cap'>{html.escape(s.caption)}</p>")
        if s.body:
            parts.append(_md_to_html(s.body))
        for p, cap in s.figures:
            with open(p, "rb") as fh:
                data = base64.b64encode(fh.read()).decode("ascii")
            parts.append(f"<figure><img alt='{html.escape(cap)}' src='data:image/png;base64,{data}'>"
                         f"<figcaption>{html.escape(cap)}</figcaption></figure>")
        parts.append("</section>")
    parts.append("</body></html>")
    with atomic_open(path, "w", encoding="utf-8") as fh:
        fh.write("\n".join(parts))
