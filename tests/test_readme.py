"""README.md stays a short user guide whose Python examples run as written.

Every ```python block of README.md is one test case (id: the block's index and its first line
that is not an import or the `jax.config` line). Each block runs in a fresh namespace, in this
process, with its own imports, and fails if it loses samples (the README's blocks are
self-contained; `tests/conftest.py` has already enabled float64, as each
block's own `jax.config.update("jax_enable_x64", True)` line does).

Shrinking for the test. The README shows realistic sizes (`n_samples=10**6`); a line may end
in a comment that shrinks it here:

    st = sj.ensemble_statistics(..., n_samples=10**6, ...)  # test: n_samples=2000

`# test: NAME=VALUE` (several pairs may follow, separated by spaces) means: on that line,
replace the first `NAME=<expression>` or `NAME = <expression>` (the expression runs up to the
next `,`, `)` or whitespace) by `NAME=VALUE` before running the block. A marker whose NAME does
not occur on its line fails the test, so the markers cannot go stale.

Also checked: the README has at most `MAX_LINES` lines, and no history ("was 4.97 s"): the
regex `was \\d` finds nothing (measurements and their history belong in benchmarks/README.md).
"""

import pathlib
import re
import warnings

import pytest

README = pathlib.Path(__file__).resolve().parents[1] / "README.md"
MAX_LINES = 365

_BLOCK = re.compile(r"^```python[ \t]*\n(.*?)^```[ \t]*$", re.S | re.M)
_MARK = re.compile(r"#\s*test:\s*(.*)$")
_PAIR = re.compile(r"(\w+)=(\S+)")


def _blocks():
    return [m.group(1) for m in _BLOCK.finditer(README.read_text(encoding="utf-8"))]


def shrink(code):
    """`code` with every `# test: NAME=VALUE` line marker applied (see the module docstring)."""
    lines = []
    for number, line in enumerate(code.splitlines(), 1):
        mark = _MARK.search(line)
        if mark:
            body, comment = line[: mark.start()], line[mark.start() :]
            pairs = _PAIR.findall(mark.group(1))
            assert pairs, f"line {number}: a '# test:' marker without NAME=VALUE: {line!r}"
            for name, value in pairs:
                body, n = re.subn(rf"\b{name}\s*=\s*[^,)\s]+", f"{name}={value}", body, count=1)
                assert n == 1, f"line {number}: the marker names {name!r}, which is not on the line"
            line = body + comment
        lines.append(line)
    return "\n".join(lines) + "\n"


def _id(index, code):
    lines = [line for line in code.splitlines() if line.strip()]
    first = next(
        (line for line in lines if not line.startswith(("import ", "from ", "jax.config"))),
        lines[0] if lines else "(empty)",
    )
    return f"{index}-{re.sub(r'[^A-Za-z0-9_.]+', '_', first).strip('_')[:40]}"


BLOCKS = _blocks()


def test_readme_has_python_blocks():
    assert len(BLOCKS) >= 5, f"found only {len(BLOCKS)} python blocks in {README}"


@pytest.mark.parametrize(
    "index,code", list(enumerate(BLOCKS)), ids=[_id(i, c) for i, c in enumerate(BLOCKS)]
)
def test_block_runs(index, code):
    source = shrink(code)
    namespace = {"__name__": f"readme_block_{index}"}
    with warnings.catch_warnings():
        # an example that loses samples (a RuntimeWarning) is a bad example
        warnings.simplefilter("error", RuntimeWarning)
        exec(compile(source, f"README.md python block {index}", "exec"), namespace)


def test_shrink_rule():
    code = (
        "x = f(a, n_samples=10**6, b=2)  # test: n_samples=10\n"
        "N = 32  # test: N=8\n"
        "y = g(steps=30, n=4)  # test: steps=2 n=1\n"
    )
    assert shrink(code).splitlines() == [
        "x = f(a, n_samples=10, b=2)  # test: n_samples=10",
        "N=8  # test: N=8",
        "y = g(steps=2, n=1)  # test: steps=2 n=1",
    ]
    with pytest.raises(AssertionError, match="not on the line"):
        shrink("x = 1  # test: n_samples=3\n")


def test_readme_is_short():
    n = len(README.read_text(encoding="utf-8").splitlines())
    assert n <= MAX_LINES, (
        f"README.md has {n} lines, at most {MAX_LINES}: move measurements "
        f"and details into benchmarks/README.md or docs/"
    )


def test_readme_has_no_history():
    hits = [
        f"{i}: {line}"
        for i, line in enumerate(README.read_text(encoding="utf-8").splitlines(), 1)
        if re.search(r"was \d", line)
    ]
    assert not hits, "history ('was <number>') belongs in benchmarks/README.md:\n" + "\n".join(hits)
