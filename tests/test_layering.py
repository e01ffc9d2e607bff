"""The package's layering, as the README's design section states it: a module imports only
modules of its own layer or below, the leaves nothing of the package, and nothing but the
command line the command-line module `_paper`. Imports inside functions count too."""

import ast
import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "slps_jax"


def _layers():
    """`{module: layer}` from the README's numbered list under "## Design"."""
    text = (ROOT / "README.md").read_text()
    design = re.search(r"^## Design.*?(?=^## |\Z)", text, re.S | re.M)
    assert design, "README.md has no '## Design' section"
    layers = {}
    for line in design.group(0).splitlines():
        m = re.match(r"^(\d+)\. (.*)", line)
        if m:
            for name in re.findall(r"`([A-Za-z_][A-Za-z0-9_]*)`", m.group(2)):
                layers.setdefault(name, int(m.group(1)))
    assert layers, "no numbered layering list in the README's design section"
    return layers


def _unit(path):
    """The top-level unit of the package a file belongs to (`_methods` for its files)."""
    rel = path.relative_to(PACKAGE)
    return rel.parts[0].removesuffix(".py")


def _imports(path):
    """The package's units imported anywhere in the file."""
    package = ["slps_jax", *path.relative_to(PACKAGE).parts[:-1]]
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                full = ".".join(base + ([node.module] if node.module else []))
            else:
                full = node.module or ""
            names = (
                [f"{full}.{a.name}" for a in node.names]
                if not node.module
                else [full] + [f"{full}.{a.name}" for a in node.names]
            )
        else:
            continue
        for name in names:
            parts = name.split(".")
            if parts[0] != "slps_jax":
                continue
            if len(parts) == 1:
                found.add("__init__")
            elif (PACKAGE / parts[1]).is_dir() or (PACKAGE / f"{parts[1]}.py").exists():
                found.add(parts[1])
            elif not node.module or len(parts) == 2 and full == "slps_jax":
                found.add("__init__")  # a name re-exported by the package
    return found


def test_every_module_has_a_layer_and_imports_none_above_it():
    layers = _layers()
    files = sorted(PACKAGE.rglob("*.py"))
    units = {_unit(f) for f in files}
    missing = units - set(layers)
    assert not missing, f"modules missing from the README's layering: {sorted(missing)}"
    wrong = []
    for f in files:
        me = _unit(f)
        for other in _imports(f) - {me}:
            if layers[other] > layers[me]:
                wrong.append(
                    f"{f.relative_to(ROOT)} ({me}, layer {layers[me]}) imports "
                    f"{other} (layer {layers[other]})"
                )
            if other == "_paper" and me != "__main__":
                wrong.append(f"{f.relative_to(ROOT)} imports the command line's _paper")
    assert not wrong, "\n".join(wrong)
    leaves = [u for u, layer in layers.items() if layer == 0]
    assert "_checks" in leaves
    for f in files:
        if _unit(f) in leaves:
            assert not _imports(f) - {_unit(f)}, f"{f.relative_to(ROOT)} is a leaf"


def test_the_checker_sees_imports():
    # the parser itself: relative, absolute and function-level imports are found
    found = _imports(PACKAGE / "_stream.py")
    assert {"_brownian", "_integrate", "_plan", "_failures", "_progress"} <= found, found
    assert "__init__" in _imports(PACKAGE / "_paper.py")
    assert "_algebra" in _imports(PACKAGE / "_methods" / "strang.py")
