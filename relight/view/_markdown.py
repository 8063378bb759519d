"""The Markdown of the project's reports (report.md) as HTML, without a Markdown package: the subset the
reports use (ATX headings, paragraphs, ``-`` / ``*`` / ``1.`` lists, pipe tables with a ``---`` separator row,
fenced and inline code, ``**bold**``, ``*emphasis*``, ``[links](url)``). Everything else is text, escaped:
nothing in a report can inject markup into the page."""

from __future__ import annotations

import html
import re

__all__ = ["markdown_html"]

_HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
_BULLET = re.compile(r"^\s*[-*+]\s+(.*)$")
_NUMBERED = re.compile(r"^\s*\d+[.)]\s+(.*)$")
_FENCE = re.compile(r"^\s*(```|~~~)")
_SEPARATOR = re.compile(r"^\s*\|?\s*:?-{3,}:?\s*(\|\s*:?-{3,}:?\s*)*\|?\s*$")
# Inline code first (its content stays literal), then links, bold, emphasis. Emphasis needs a non-space
# after the opening star, so "2 * 3 * 4" and snake_case names stay as they are.
_CODE = re.compile(r"`([^`]+)`")
_LINK = re.compile(r"\[([^\]]+)\]\(([^)\s]+)\)")
_BOLD = re.compile(r"\*\*(?=\S)(.+?)(?<=\S)\*\*")
_EM = re.compile(r"(?<![\w*])\*(?=\S)([^*]+?)(?<=\S)\*(?![\w*])")
# Links keep only these schemes (and relative paths): a javascript: URL in a report is shown as text.
_SAFE_URL = re.compile(r"^(https?:|mailto:|#|\.{0,2}/|[\w.-]+(/|$|\.))", re.IGNORECASE)


def _inline(text: str) -> str:
    """One line or cell: HTML-escaped, with inline code, links, bold and emphasis."""
    codes: list[str] = []

    def keep(m):
        codes.append(f"<code>{html.escape(m.group(1))}</code>")
        return f"\x00{len(codes) - 1}\x00"

    out = html.escape(_CODE.sub(keep, text), quote=True)

    def link(m):
        url = html.unescape(m.group(2))
        if not _SAFE_URL.match(url):
            return m.group(0)
        return f'<a href="{html.escape(url, quote=True)}">{m.group(1)}</a>'

    out = _LINK.sub(link, out)
    out = _BOLD.sub(r"<strong>\1</strong>", out)
    out = _EM.sub(r"<em>\1</em>", out)
    return re.sub("\x00(\\d+)\x00", lambda m: codes[int(m.group(1))], out)


def _cells(row: str) -> list[str]:
    row = row.strip()
    if row.startswith("|"):
        row = row[1:]
    if row.endswith("|") and not row.endswith("\\|"):
        row = row[:-1]
    return [c.strip().replace("\\|", "|") for c in re.split(r"(?<!\\)\|", row)]


def _table(lines: list[str]) -> str:
    head, body = _cells(lines[0]), [_cells(r) for r in lines[2:]]
    n = len(head)
    rows = ["<table>", "<thead><tr>" + "".join(f"<th>{_inline(c)}</th>" for c in head) + "</tr></thead>", "<tbody>"]
    for r in body:
        r = (r + [""] * n)[:n]
        rows.append("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>")
    rows += ["</tbody>", "</table>"]
    return "\n".join(rows)


def _list(lines: list[str], i: int, pattern: re.Pattern, tag: str) -> tuple[str, int]:
    """The list starting at line ``i`` (items of ``pattern``, indented continuation lines joined to their item)
    as HTML, and the index of the first line after it."""
    items: list[str] = []
    while i < len(lines) and lines[i].strip():
        item = pattern.match(lines[i])
        if item:
            items.append(item.group(1))
        elif items and lines[i].startswith((" ", "\t")):
            items[-1] += " " + lines[i].strip()
        else:
            break
        i += 1
    return f"<{tag}>" + "".join(f"<li>{_inline(x)}</li>" for x in items) + f"</{tag}>", i


def markdown_html(text: str, heading_offset: int = 0) -> str:
    """HTML for the Markdown ``text`` (the subset in the module docstring); every other character is escaped.
    ``heading_offset`` demotes headings (1: ``#`` becomes ``<h2>``; at most ``<h6>``), so a report's title
    sits under the page's own."""
    if not isinstance(text, str):
        raise ValueError(f"text must be a str, got {type(text).__name__}")
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    out: list[str] = []
    para: list[str] = []
    i = 0

    def flush() -> None:
        if para:
            out.append("<p>" + " ".join(_inline(p.strip()) for p in para) + "</p>")
            para.clear()

    while i < len(lines):
        line = lines[i]
        if not line.strip():
            flush()
            i += 1
            continue
        fence = _FENCE.match(line)
        if fence:
            flush()
            j = i + 1
            while j < len(lines) and not lines[j].strip().startswith(fence.group(1)):
                j += 1
            out.append("<pre><code>" + html.escape("\n".join(lines[i + 1:j])) + "</code></pre>")
            i = j + 1
            continue
        m = _HEADING.match(line)
        if m:
            flush()
            level = min(6, len(m.group(1)) + max(0, int(heading_offset)))
            out.append(f"<h{level}>{_inline(m.group(2))}</h{level}>")
            i += 1
            continue
        if "|" in line and i + 1 < len(lines) and _SEPARATOR.match(lines[i + 1]) and "-" in lines[i + 1]:
            flush()
            j = i + 2
            while j < len(lines) and lines[j].strip() and "|" in lines[j]:
                j += 1
            out.append(_table(lines[i:j]))
            i = j
            continue
        for pattern, tag in ((_BULLET, "ul"), (_NUMBERED, "ol")):
            if pattern.match(line):
                flush()
                html_list, i = _list(lines, i, pattern, tag)
                out.append(html_list)
                break
        else:
            para.append(line)
            i += 1
    flush()
    return "\n".join(out)
