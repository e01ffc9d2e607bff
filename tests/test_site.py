"""The documentation site (mkdocs.yml) stays complete, without building it (`.ci/run` builds it
with `mkdocs build --strict`, which reports broken links and anchors):

- every public name has an entry `::: slps_jax.NAME` in the API reference (`docs/api/*.md`):
  the package's public names (its `__all__` if it has one, else every public name it
  binds that is not a module), and those of `slps_jax.so3`, `slps_jax.zeitlin` and `slps_jax.sphere` (their
  `__all__`, else the functions and classes they define and their public constants), as
  `::: slps_jax.so3.NAME`;
- every page in `docs/` and every notebook in `notebooks/` is in the site's nav;
- every public function's docstring is in the house style, with an `**Arguments:**` section
  (when it takes parameters) and a `**Returns:**` section, and so is every class a user
  constructs (`**Arguments:**`), except the result containers and abstract interfaces of
  `_HOUSE_STYLE_EXEMPT`.
"""

import __future__

import inspect
import pathlib
import re
import types

import pytest

import slps_jax

# the public modules: the package and its toolkits (tests/test_api.py checks the list)
MODULES = [slps_jax, slps_jax.so3, slps_jax.zeitlin, slps_jax.sphere]

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

_ENTRY = re.compile(r"^:::[ \t]+([\w.]+)[ \t]*$", re.M)


def _public_names(module):
    names = getattr(module, "__all__", None)
    if names is not None:
        return set(names)
    found = set()
    for name, value in vars(module).items():
        if name.startswith("_") or isinstance(value, (types.ModuleType, __future__._Feature)):
            continue
        if inspect.isclass(value) or callable(value):
            # defined in the package (a submodule's imports from jax, numpy are not its own)
            if not getattr(value, "__module__", "").startswith("slps_jax"):
                continue
        found.add(name)
    return found


def _api_entries():
    return {
        m
        for page in (DOCS / "api").glob("*.md")
        for m in _ENTRY.findall(page.read_text(encoding="utf-8"))
    }


def _nav_paths():
    text = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    nav = re.search(r"^nav:[ \t]*\n((?:[ \t]+.*\n?|\n)*)", text, re.M)
    assert nav, "mkdocs.yml has no nav"
    return set(re.findall(r"([\w./-]+\.(?:md|ipynb))[ \t]*(?:#.*)?$", nav.group(1), re.M))


@pytest.mark.parametrize("module", MODULES, ids=lambda m: m.__name__)
def test_every_public_name_has_an_api_entry(module):
    names = _public_names(module)
    assert names, f"{module.__name__}: no public names found"
    missing = sorted({f"{module.__name__}.{n}" for n in names} - _api_entries())
    assert not missing, f"no `::: NAME` entry in docs/api/*.md for: {', '.join(missing)}"


@pytest.mark.parametrize("module", MODULES, ids=lambda m: m.__name__)
def test_every_public_name_has_a_docstring(module):
    """At run time too (`help`, an editor's hover), not only in the site: a summary line at
    least."""
    bare = sorted(
        n
        for n in _public_names(module)
        if inspect.isclass(getattr(module, n)) or callable(getattr(module, n))
        if len((inspect.getdoc(getattr(module, n)) or "").strip()) < 20
    )
    assert not bare, f"{module.__name__}: public names without a docstring: {bare}"


def test_api_entries_name_public_objects():
    """An entry that names nothing public (a removed or renamed name) is caught here, not only
    by the site build."""
    public = {f"{m.__name__}.{n}" for m in MODULES for n in _public_names(m)} | {
        m.__name__ for m in MODULES[1:]
    }
    stale = sorted(_api_entries() - public)
    assert not stale, f"docs/api/*.md has entries for names that are not public: {stale}"


def test_every_page_and_notebook_is_in_the_nav():
    pages = {p.relative_to(DOCS).as_posix() for p in DOCS.rglob("*.md")}
    notebooks = {p.relative_to(ROOT).as_posix() for p in (ROOT / "notebooks").glob("*.ipynb")}
    nav = _nav_paths()
    missing = sorted((pages | notebooks) - nav)
    assert not missing, f"not in mkdocs.yml's nav: {missing}"
    absent = sorted(p for p in nav if not ((DOCS / p).is_file() or (ROOT / p).is_file()))
    assert not absent, f"mkdocs.yml's nav names files that do not exist: {absent}"


# Public names that need not carry the `**Arguments:**` / `**Returns:**` sections:
_HOUSE_STYLE_EXEMPT = {
    # result containers: built by the library, not the user; their docstrings list the fields
    **dict.fromkeys(
        (
            "AmplitudeTuning",
            "ModelErrorVariance",
            "CalibrationResult",
            "FilterResult",
            "KalmanResult",
            "Checkpoint",
            "ConvergenceResult",
            "EnsembleStatistics",
            "ForecastScores",
            "PairedComparison",
            "Solution",
            "StepInfo",
            "StoredRun",
            "StrongOrders",
            "TransportNoiseFit",
            "ClosureFit",
            "WeakConvergenceResult",
        ),
        "a result container: its docstring lists its fields",
    ),
    # interfaces to subclass: their docstrings list what a subclass writes
    **dict.fromkeys(
        ("AbstractAlgebra", "AbstractLiePoissonSystem", "AbstractMethod", "AbstractNoise"),
        "an abstract interface: its docstring lists what a subclass writes",
    ),
}


def _takes_parameters(obj):
    try:
        parameters = inspect.signature(obj).parameters
    except (TypeError, ValueError):  # (no signature to read: a builtin)
        return False
    return any(p.name != "self" for p in parameters.values())


@pytest.mark.parametrize("module", MODULES, ids=lambda m: m.__name__)
def test_public_functions_follow_the_house_style(module):
    """Every public function has `**Arguments:**` (when it takes parameters) and
    `**Returns:**`; every public class a user constructs has `**Arguments:**` for its
    constructor (when it takes parameters). Exempt: `_HOUSE_STYLE_EXEMPT`."""
    stale = sorted(set(_HOUSE_STYLE_EXEMPT) - _public_names(slps_jax))
    assert not stale, f"_HOUSE_STYLE_EXEMPT names that are not public: {stale}"
    missing = []
    for name in sorted(_public_names(module)):
        obj = getattr(module, name)
        is_class = inspect.isclass(obj)
        if not (is_class or callable(obj)) or name in _HOUSE_STYLE_EXEMPT:
            continue
        doc = inspect.getdoc(obj) or ""
        lacks = [
            section
            for section, needed in (
                ("**Arguments:**", _takes_parameters(obj)),
                ("**Returns:**", not is_class),
            )
            if needed and section not in doc
        ]
        if lacks:
            missing.append(f"{name} ({', '.join(lacks)})")
    assert not missing, (
        f"{module.__name__}: public names whose docstring lacks a house-style section: "
        + "; ".join(missing)
    )


def _offline_hooks():
    """docs/offline.py, the site's hooks (the docs extra: mkdocs, latex2mathml)."""
    pytest.importorskip("mkdocs")
    pytest.importorskip("latex2mathml")
    import importlib.util

    spec = importlib.util.spec_from_file_location("docs_offline", DOCS / "offline.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_offline_check_finds_every_kind_of_load(tmp_path):
    """`mkdocs build` fails on anything a page fetches from another host
    (`offline.external_loads`): scripts, stylesheets, images, CSS `url()` and `@import`, a
    script's `import()`; a link a reader follows is not a load."""
    offline = _offline_hooks()
    (tmp_path / "page").mkdir()
    (tmp_path / "page" / "index.html").write_text(
        '<script src="https://cdn.example/a.js"></script>'
        '<link rel="stylesheet" href="//fonts.example/b.css">'
        "<img src='http://img.example/c.png'>"
        '<a href="https://doi.org/10.1017/jfm.2019.944">a citation</a>'
        '<script src="../assets/local.js"></script>'
        '<script>if (x) import("https://cdnjs.example/mermaid.js")</script>',
        encoding="utf-8",
    )
    (tmp_path / "style.css").write_text(
        '@import "https://fonts.example/d.css"; p { background: url(https://e.example/e.png) }',
        encoding="utf-8",
    )
    found = offline.external_loads(tmp_path)
    assert sorted(found) == sorted(
        [
            "page/index.html: https://cdn.example/a.js",
            "page/index.html: //fonts.example/b.css",
            "page/index.html: http://img.example/c.png",
            "page/index.html: https://cdnjs.example/mermaid.js",
            "style.css: https://fonts.example/d.css",
            "style.css: https://e.example/e.png",
        ]
    )


def test_page_math_becomes_mathml():
    """The pages' formulas (arithmatex's spans and divs, a notebook cell's `$...$` outside
    code) are replaced by MathML at build time, HTML entities read as TeX; a formula the
    converter cannot read fails the build, naming the page. mkdocs-jupyter's script that
    would import mermaid.js from a CDN is dropped, other scripts kept."""
    offline = _offline_hooks()
    page = types.SimpleNamespace(file=types.SimpleNamespace(src_uri="x.md"))
    out = offline.on_post_page(
        '<p>a <span class="arithmatex">\\(x &lt; \\tfrac12\\)</span> b</p>'
        '<div class="arithmatex">\\[\\sum_r \\Delta W_r\\]</div>'
        '<div class="jp-RenderedHTMLCommon jp-RenderedMarkdown">'
        "<p>cost $O(N^3)$ and <code>$HOME</code></p></div>"
        '<script type="module">if (d.length) { const mermaid = (await import('
        '"https://cdnjs.example/mermaid.esm.min.mjs")).default; }</script>'
        "<script>keep()</script>",
        page,
        None,
    )
    assert "arithmatex" not in out and "\\(" not in out and "$O(N^3)$" not in out
    assert out.count("<math") == 3 and out.count('display="block"') == 1
    assert "&lt;</mo>" in out or "&#x0003C;</mo>" in out  # the entity read as "<"
    assert "<code>$HOME</code>" in out
    assert "cdnjs" not in out and "<script>keep()</script>" in out  # (mkdocs-jupyter's loader)
    for bad in ("\\left( x", "\\foo x"):  # (unbalanced; a command it does not know)
        with pytest.raises(Exception, match="x.md"):
            offline.on_post_page(f'<span class="arithmatex">\\({bad}\\)</span>', page, None)
