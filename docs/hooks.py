"""MkDocs hooks: the site is built from files that live outside `docs/` without copying them.

- **Includes.** A line `--8<-- "PATH"` in a page (the syntax of pymdownx.snippets; PATH
  relative to the repository root) is replaced by that file's text: `docs/index.md` is the
  README, `docs/benchmarks.md` is `benchmarks/README.md`.
- **Links.** Every relative link (inline, image or reference definition, outside code) is
  read as written in its source file, README.md, `benchmarks/README.md` or the page itself,
  so that the same Markdown works on GitHub and in the site: `docs/x.md` from the README
  becomes `x.md`, `../docs/x.png` from `benchmarks/README.md` becomes `../x.png`, a link to
  an included file goes to the page that includes it.
- **Files outside `docs/`.** The notebooks (`notebooks/*.ipynb`, rendered by mkdocs-jupyter)
  and any other file of the repository that a page links to (`examples/multiprocess.py`) are
  added to the site under their repository path, so that the links resolve.

A link that resolves to nothing is left as written, for `mkdocs build --strict` to report.
"""

from __future__ import annotations

import logging
import posixpath
import re
from pathlib import Path

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File, Files, InclusionLevel

log = logging.getLogger("mkdocs.hooks.slps_jax")

_INCLUDE = re.compile(r"""^[ \t]*--8<--[ \t]+["']([^"']+)["'][ \t]*$""", re.M)
_FENCE = re.compile(r"^[ \t]*(`{3,}|~{3,})")
_CODE_SPAN = re.compile(r"(`+)(?:.+?)\1")
# [text](target "title") and ![alt](target): the target up to whitespace or the closing ")"
_INLINE = re.compile(r"(\]\(\s*<?)([^)\s>]+)(>?(?:\s+(?:\"[^\"]*\"|'[^']*'))?\s*\))")
_REFERENCE = re.compile(r"^([ ]{0,3}\[[^\]^][^\]]*\]:[ \t]*<?)(\S+?)(>?(?:[ \t].*)?)$")  # not [^1]:
_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")

_root = Path()
_docs = Path()
_included_by: dict[str, str] = {}  # repository path of an included file -> the page's src_uri


def on_config(config):
    global _root, _docs
    _root = Path(config.config_file_path).resolve().parent
    _docs = Path(config.docs_dir).resolve()


def _repo_path(abs_path) -> str:
    return Path(abs_path).resolve().relative_to(_root).as_posix()


def _docs_prefix() -> str:
    return _docs.relative_to(_root).as_posix() + "/"


def _segments(text: str, source: str, warn: bool = False):
    """The page's text as (text, repository path it was written in) pieces, includes expanded."""
    pieces, start = [], 0
    for m in _INCLUDE.finditer(text):
        pieces.append((text[start : m.start()], source))
        included = m.group(1)
        path = _root / included
        if not path.is_file():
            if warn:
                log.warning("%s: includes %r, which does not exist", source, included)
            pieces.append((m.group(0), source))
        else:
            pieces.append((path.read_text(encoding="utf-8"), included))
        start = m.end()
    pieces.append((text[start:], source))
    return pieces


def _targets(text: str):
    """The link targets of Markdown text, outside fenced code and code spans."""
    found = []
    _map_links(text, lambda t: found.append(t) or t)
    return found


def _map_links(text: str, f) -> str:
    """`text` with each link target `t` outside code replaced by `f(t)`."""
    out, fence = [], None
    for line in text.splitlines(keepends=True):
        m = _FENCE.match(line)
        if fence is not None:
            if m and m.group(1)[0] == fence[0] and len(m.group(1)) >= len(fence):
                fence = None
            out.append(line)
            continue
        if m:
            fence = m.group(1)
            out.append(line)
            continue
        ref = _REFERENCE.match(line.rstrip("\n"))
        if ref:
            end = line[len(line.rstrip("\n")) :]
            out.append(ref.group(1) + f(ref.group(2)) + ref.group(3) + end)
            continue
        # links in the prose between code spans
        sub = lambda prose: _INLINE.sub(lambda k: k.group(1) + f(k.group(2)) + k.group(3), prose)
        parts, pos = [], 0
        for span in _CODE_SPAN.finditer(line):
            parts += [sub(line[pos : span.start()]), span.group(0)]
            pos = span.end()
        out.append("".join(parts) + sub(line[pos:]))
    return "".join(out)


def _split(target: str):
    """(path, '#fragment' or '?query...' or '') of a relative link, or None for other links."""
    if not target or target.startswith(("#", "/")) or _SCHEME.match(target):
        return None
    cut = min((i for i in (target.find("#"), target.find("?")) if i >= 0), default=len(target))
    return target[:cut], target[cut:]


def _resolve(target: str, source: str):
    """The repository path a relative link written in `source` points at, and its fragment."""
    split = _split(target)
    if split is None or not split[0]:
        return None
    path = posixpath.normpath(posixpath.join(posixpath.dirname(source), split[0]))
    if path == ".." or path.startswith("../"):
        return None
    return path, split[1]


def _site_uri(path: str, files: Files):
    """The src_uri in the site of a repository file (a folder: its README.md or index.md), or
    None."""
    if (_root / path).is_dir():
        for index in ("README.md", "index.md"):
            uri = _site_uri(posixpath.normpath(posixpath.join(path, index)), files)
            if uri is not None:
                return uri
        return None
    if path in _included_by:
        return _included_by[path]
    prefix = _docs_prefix()
    if path.startswith(prefix):
        uri = path[len(prefix) :]
        return uri if files.get_file_from_path(uri) is not None else None
    return path if files.get_file_from_path(path) is not None else None


@event_priority(100)  # before mkdocs-jupyter (priority 0) wraps the notebooks as pages
def on_files(files: Files, config) -> Files:
    _included_by.clear()
    site = dict(dest_dir=config.site_dir, use_directory_urls=config.use_directory_urls)
    texts = []  # (text, source) pairs to scan for links to files outside docs/
    for file in files.documentation_pages():
        if file.abs_src_path is None:  # (generated by a plugin: no source to read)
            continue
        text = Path(file.abs_src_path).read_text(encoding="utf-8")
        source = _repo_path(file.abs_src_path)
        for included in _INCLUDE.findall(text):
            _included_by.setdefault(posixpath.normpath(included), file.src_uri)
        texts.extend(_segments(text, source))

    for notebook in sorted((_root / "notebooks").glob("*.ipynb")):
        files.append(File(_repo_path(notebook), src_dir=str(_root), **site))

    prefix = _docs_prefix()
    while texts:
        text, source = texts.pop()
        for target in _targets(text):
            resolved = _resolve(target, source)
            if resolved is None:
                continue
            path = resolved[0]
            if path.startswith(prefix) or path in _included_by:
                continue
            if files.get_file_from_path(path) is not None or not (_root / path).is_file():
                continue
            file = File(path, src_dir=str(_root), **site)
            if file.is_documentation_page():  # a page of its own, not in the nav
                file.inclusion = InclusionLevel.NOT_IN_NAV
                texts.append(((_root / path).read_text(encoding="utf-8"), path))
            files.append(file)
    return files


def on_page_markdown(markdown: str, page, config, files: Files) -> str:
    page_dir = posixpath.dirname(page.file.src_uri)

    def rebase(source):
        def f(target):
            resolved = _resolve(target, source)
            if resolved is None:
                return target
            uri = _site_uri(resolved[0], files)
            if uri is None:
                return target  # left for mkdocs to report
            return posixpath.relpath(uri, page_dir or ".") + resolved[1]

        return f

    if page.file.abs_src_path is None:
        return markdown
    source = _repo_path(page.file.abs_src_path)
    pieces = _segments(markdown, source, warn=True)
    return "".join(_map_links(text, rebase(src)) for text, src in pieces)
