"""The README and the guide (`docs/*.md`) show Python that runs as written and prints what
they say it prints.

Every ```python block of README.md and of each `docs/*.md` page is one test case (id: the
file, the block's index and its first line that is not an import or the `jax.config` line).
Each block runs in a fresh namespace, in this process, with its own imports, and fails if it
loses samples (a `RuntimeWarning`); `tests/conftest.py` has already enabled float64, as each
block's own `jax.config.update("jax_enable_x64", True)` line does.

Every python block is followed, with only blank lines between, by a ```text block: what the
block prints, checked. Words and punctuation must match exactly; a number matches when it is
within one unit of the expected number's last printed digit (`2.02` matches 2.0249 and
2.0151; `1.7e-04` matches 1.6e-04 ... 1.8e-04), so that the text states what a reader sees
and the test still fails when a result moves. The blocks run at the sizes shown: a reader
copies them as they are.

Four blocks reproduce a documented study at its documented size (a strong-convergence
study with its reference, a fine run with its fit and forecast, a forced-dissipative run and
its closure, a closure trained and scored), a few minutes of the suite between them: they
are full-size checks, run by the second tier (`-m full`, `.ci/run` after the README's
command), as `FULL_SIZE` lists.

Also checked: the README has at most `MAX_LINES` lines, and no history ("was 4.97 s"): the
regex `was \\d` finds nothing (measurements and their history belong in benchmarks/README.md).
"""

import contextlib
import io
import pathlib
import re
import warnings

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]
MAX_LINES = 250

_BLOCK = re.compile(
    r"^```python[ \t]*\n(.*?)^```[ \t]*\n(?:[ \t]*\n)*(?:```text[ \t]*\n(.*?)^```)?", re.S | re.M
)
_NUMBER = r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?"
_TOKEN = re.compile(rf"{_NUMBER}|[A-Za-z_]\w*|\S")


def _blocks():
    out = []
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        for index, m in enumerate(_BLOCK.finditer(text)):
            out.append((page.relative_to(ROOT).as_posix(), index, m.group(1), m.group(2)))
    return out


def _id(page, index, code):
    lines = [line for line in code.splitlines() if line.strip()]
    first = next(
        (line for line in lines if not line.startswith(("import ", "from ", "jax.config"))),
        lines[0] if lines else "(empty)",
    )
    return f"{page}-{index}-{re.sub(r'[^A-Za-z0-9_.]+', '_', first).strip('_')[:40]}"


def _is_number(token):
    return re.fullmatch(_NUMBER, token) is not None


def _unit(token):
    """One unit of the last printed digit of the number `token`."""
    mantissa, _, exponent = token.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    return 10.0 ** (int(exponent or 0) - decimals)


def matches(printed, expected):
    """`None` when `printed` reads as `expected` (see the module docstring), else the first
    difference, in words."""
    got, want = _TOKEN.findall(printed), _TOKEN.findall(expected)
    for i, (g, w) in enumerate(zip(got, want)):
        if _is_number(w) and _is_number(g):
            if abs(float(g) - float(w)) > 1.01 * _unit(w) + 1e-300:
                return f"token {i}: printed {g}, the text says {w}"
        elif g != w:
            return f"token {i}: printed {g!r}, the text says {w!r}"
    if len(got) != len(want):
        return f"printed {len(got)} tokens, the text shows {len(want)}"
    return None


BLOCKS = _blocks()

FULL_SIZE = {
    ("docs/levy-area.md", 0): "strong_convergence of 100 samples to a 2^-12 reference",
    ("docs/data-driven-noise.md", 0): "a 44-second su(32) run, its fit and a 32-member forecast",
    ("docs/data-driven-noise.md", 1): "a forced-dissipative su(32) run of 50 s and its closure",
    ("docs/data-driven-noise.md", 2): "a forced-dissipative su(16) run, its closure trained",
}


def _case(page, index, code, expected):
    marks = [pytest.mark.full] if (page, index) in FULL_SIZE else []
    return pytest.param(page, index, code, expected, marks=marks, id=_id(page, index, code))


def test_pages_have_python_blocks():
    readme = [b for b in BLOCKS if b[0] == "README.md"]
    assert readme and len(BLOCKS) >= 10, f"found {len(readme)} README and {len(BLOCKS)} blocks"


def test_the_full_size_blocks_are_there():
    assert set(FULL_SIZE) <= {(page, index) for page, index, _, _ in BLOCKS}


@pytest.mark.parametrize("page,index,code,expected", [_case(*b) for b in BLOCKS])
def test_block_prints_what_the_text_says(page, index, code, expected):
    assert expected is not None, (
        f"{page}, python block {index}: follow it with a ```text block of what it prints"
    )
    namespace = {"__name__": f"docs_block_{index}"}
    stdout = io.StringIO()
    with warnings.catch_warnings(), contextlib.redirect_stdout(stdout):
        # an example that loses samples (a RuntimeWarning) is a bad example
        warnings.simplefilter("error", RuntimeWarning)
        exec(compile(code, f"{page} python block {index}", "exec"), namespace)
    printed = stdout.getvalue()
    difference = matches(printed, expected)
    assert difference is None, f"{page}, block {index}: {difference}\nprinted:\n{printed}"


def test_matching_rule():
    assert matches("(1000, 1, 3)\n2.0249\n", "(1000, 1, 3)\n2.02") is None
    assert matches("2.04", "2.02") is not None  # two units of the last digit
    assert matches("1.64e-04", "1.7e-04") is None
    assert matches("1.5e-04", "1.7e-04") is not None
    assert matches("LP 1.0", "EM 1.0") is not None
    assert matches("True", "True\nFalse") is not None  # a line missing
    assert matches("[2, 3, 2]", "[2, 3, 2]") is None


def test_readme_is_short():
    n = len(README.read_text(encoding="utf-8").splitlines())
    assert n <= MAX_LINES, (
        f"README.md has {n} lines, at most {MAX_LINES}: it is the landing page; the guide is "
        f"in docs/, measurements in benchmarks/README.md"
    )


def test_benchmarks_readme_is_short():
    # one table per measurement, each on one named machine: not a log of every run
    n = len((ROOT / "benchmarks" / "README.md").read_text(encoding="utf-8").splitlines())
    assert n <= 400, f"benchmarks/README.md has {n} lines, at most 400"


def test_readme_has_no_history():
    hits = [
        f"{i}: {line}"
        for i, line in enumerate(README.read_text(encoding="utf-8").splitlines(), 1)
        if re.search(r"was \d", line)
    ]
    assert not hits, "history ('was <number>') belongs in benchmarks/README.md:\n" + "\n".join(hits)
