"""MkDocs hooks: a site that reads offline, on clusters and machines without the internet.

- **Math as MathML, at build time.** Every formula, `$...$` and `$$...$$` of the pages and
  the docstrings (pymdownx.arithmatex, generic mode) and of the notebooks' Markdown cells
  (mkdocs-jupyter leaves them as written), is converted to MathML by `latex2mathml` (pure
  Python, the docs extra). Browsers render MathML themselves: no script, no CDN. A formula
  it cannot convert, or with a command it does not know, fails the build, naming the page
  and the formula.
- **No diagram loader.** mkdocs-jupyter adds to every notebook page a script that imports
  mermaid.js from a CDN when the page has a Mermaid diagram; the notebooks have none, and
  the script is dropped (a diagram would show as its source).
- **Nothing loaded from another host.** After the build, every page and stylesheet is
  scanned for a script, stylesheet, image, font or import fetched from an absolute URL
  (`http:`, `https:`, `//`); one fails the build, naming the file and the URL. Links that a
  reader follows (`<a href>`) are not loads and stay as written.
"""

from __future__ import annotations

import html
import re
from pathlib import Path

from latex2mathml.converter import convert
from mkdocs.exceptions import PluginError

# pymdownx.arithmatex, generic: \(...\) in a span, \[...\] in a div, HTML-escaped
_ARITHMATEX = re.compile(r'<(span|div) class="arithmatex">\s*\\([(\[])(.*?)\\[)\]]\s*</\1>', re.S)
# a notebook's rendered Markdown cell (nbconvert): its text keeps $...$ and $$...$$
_NOTEBOOK_MARKDOWN = re.compile(
    r'(<div class="[^"]*\bjp-RenderedMarkdown\b[^"]*"[^>]*>)(.*?)(</div>)', re.S
)
_UNKNOWN = re.compile(r">(\\[A-Za-z]+)<")
# mkdocs-jupyter's module script that imports mermaid.js from a CDN for Mermaid cells
_MERMAID_LOADER = re.compile(r'<script type="module">(?:(?!</script>).)*?mermaid.*?</script>', re.S)
_CODE = re.compile(r"(<(code|pre)\b.*?</\2>)", re.S)
_DOLLARS = re.compile(r"\$\$(.+?)\$\$|(?<![\\$])\$(?!\s)([^$\n]+?)(?<!\s)\$(?!\d)", re.S)
# what a page or stylesheet loads: src=, a stylesheet's or icon's href, CSS url() and
# @import, and a module import in a script
_LOADS = re.compile(
    r"""\bsrc\s*=\s*["']?((?:https?:)?//[^"'\s>]+)"""
    r"""|<link\b[^>]*\bhref\s*=\s*["']((?:https?:)?//[^"'\s>]+)"""
    r"""|url\(\s*["']?((?:https?:)?//[^"')\s]+)"""
    r"""|@import\s+["']((?:https?:)?//[^"']+)"""
    r"""|\bimport\s*\(\s*["']((?:https?:)?//[^"']+)""",
    re.I,
)


def _mathml(tex: str, display: bool, where: str) -> str:
    try:
        out = convert(tex, display="block" if display else "inline")
    except Exception as error:  # (the converter's errors have no common base)
        raise PluginError(
            f"{where}: cannot convert the formula {tex!r} to MathML: {error!r}"
        ) from error
    if "<merror" in out:
        raise PluginError(f"{where}: the formula {tex!r} converts to a MathML error")
    unknown = _UNKNOWN.search(out)
    if unknown:  # (the converter writes a command it does not know as text)
        raise PluginError(f"{where}: the formula {tex!r} uses {unknown.group(1)}, unknown to it")
    return out


def _notebook_math(block: str, where: str) -> str:
    """`$...$` and `$$...$$` in a rendered Markdown cell, outside code, as MathML."""

    def convert_text(text):
        return _DOLLARS.sub(
            lambda m: _mathml(html.unescape(m.group(1) or m.group(2)), bool(m.group(1)), where),
            text,
        )

    parts = _CODE.split(block)
    # (split keeps each code element and its tag name: text, code, tag, text, ...)
    return "".join(
        part if i % 3 else convert_text(part) for i, part in enumerate(parts) if i % 3 != 2
    )


def on_post_page(output: str, page, config) -> str:
    where = page.file.src_uri
    output = _ARITHMATEX.sub(
        lambda m: _mathml(html.unescape(m.group(3)), m.group(2) == "[", where), output
    )
    output = _MERMAID_LOADER.sub("", output)
    return _NOTEBOOK_MARKDOWN.sub(
        lambda m: m.group(1) + _notebook_math(m.group(2), where) + m.group(3), output
    )


def external_loads(site_dir) -> list[str]:
    """`FILE: URL` for everything a built page or stylesheet fetches from another host."""
    found = []
    for path in sorted(Path(site_dir).rglob("*")):
        if path.suffix not in (".html", ".css", ".js") or not path.is_file():
            continue
        text = path.read_text(encoding="utf-8", errors="replace")
        for m in _LOADS.finditer(text):
            url = next(g for g in m.groups() if g)
            found.append(f"{path.relative_to(site_dir).as_posix()}: {url}")
    return found


def on_post_build(config) -> None:
    found = external_loads(config.site_dir)
    if found:
        raise PluginError(
            f"the site loads {len(found)} resource(s) from other hosts, so it would not read "
            "offline:\n  " + "\n  ".join(found[:20])
        )
