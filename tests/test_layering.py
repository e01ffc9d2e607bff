"""The package's layering, as the package declares it (`slps_jax._LAYERS`, read from the
source): a unit (a subpackage, or a module at the top) imports only units of its own layer
or below, the leaves nothing of the package; every unit has a layer, and docs/design.md's
design section names every unit. Imports inside functions count too."""

import ast
import pathlib

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "slps_jax"


def _layers():
    """`{unit: layer}` from `_LAYERS` in `slps_jax/__init__.py` (read, not imported)."""
    tree = ast.parse((PACKAGE / "__init__.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and [t.id for t in node.targets] == ["_LAYERS"]:
            layers = ast.literal_eval(node.value)
            return {unit: k for k, units in enumerate(layers) for unit in units}
    raise AssertionError("slps_jax/__init__.py declares no _LAYERS")


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
    assert not missing, f"units missing from slps_jax._LAYERS: {sorted(missing)}"
    stale = set(layers) - units
    assert not stale, f"slps_jax._LAYERS names units that do not exist: {sorted(stale)}"
    design = (ROOT / "docs" / "design.md").read_text(encoding="utf-8")
    unnamed = {u for u in units if f"`{u}`" not in design} - {"__init__", "__main__"}
    assert not unnamed, f"docs/design.md does not name {sorted(unnamed)}"
    wrong = []
    for f in files:
        me = _unit(f)
        for other in _imports(f) - {me}:
            if layers[other] > layers[me]:
                wrong.append(
                    f"{f.relative_to(ROOT)} ({me}, layer {layers[me]}) imports "
                    f"{other} (layer {layers[other]})"
                )
    assert not wrong, "\n".join(wrong)
    leaves = [u for u, layer in layers.items() if layer == 0]
    assert "_support" in leaves
    for f in files:
        if _unit(f) in leaves:
            assert not _imports(f) - {_unit(f)}, f"{f.relative_to(ROOT)} is a leaf"


def test_the_checker_sees_imports():
    # the parser itself: relative, absolute and function-level imports are found
    found = _imports(PACKAGE / "_driver" / "stream.py")
    assert {"_brownian", "_driver", "_support"} <= found, found
    assert "__init__" in _imports(PACKAGE / "_cli" / "paper.py")
    assert "_algebra" in _imports(PACKAGE / "_methods" / "strang.py")


def _module(path):
    """The dotted name of a file of the package (a package's `__init__.py`: the package)."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _module_graph():
    """`{module: modules of the package it imports}`, anywhere in the file. `from P import m`
    of a submodule `m` depends on `P.m`, not on the package `P`'s own code."""
    modules = {_module(p): p for p in PACKAGE.rglob("*.py")}
    graph = {}
    for me, path in modules.items():
        package = me.split(".") if path.name == "__init__.py" else me.split(".")[:-1]
        edges = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = package[: len(package) - node.level + 1] if node.level else []
                full = ".".join(base + [node.module] if node.module else base)
                full = full if node.level else (node.module or "")
                subs = [f"{full}.{a.name}" for a in node.names]
                names = subs if all(s in modules for s in subs) else [full, *subs]
            else:
                continue
            edges |= {n for n in names if n in modules and n != me}
        graph[me] = edges
    return graph


def _circles(graph):
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, found = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while not component or component[-1] != v:
                component.append(stack.pop())
                on.discard(component[-1])
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_module_imports_itself_through_others():
    # Layers allow imports both ways within a unit; a circle of modules is refused anyway,
    # imports inside functions included (they only defer one).
    assert _circles(_module_graph()) == []


def test_the_circle_check_sees_a_circle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _circles(graph) == [["a", "b", "c"]]
    # and the graph has the package's edges: rigid_body builds on system (`from .system import`)
    assert "slps_jax._systems.system" in _module_graph()["slps_jax._systems.rigid_body"]


def _mentions_system(source):
    """The lines of a module's code (not its strings) that name a system: a variable,
    parameter or attribute called `system`, or a name from `_systems`."""
    found = []
    for node in ast.walk(ast.parse(source)):
        name = (
            node.id
            if isinstance(node, ast.Name)
            else node.arg
            if isinstance(node, ast.arg)
            else node.attr
            if isinstance(node, ast.Attribute)
            else None
        )
        if name in ("system", "systems") or (
            isinstance(node, ast.ImportFrom) and "_systems" in (node.module or "")
        ):
            found.append(node.lineno)
    return found


def test_no_algebra_module_refers_to_a_system():
    # An algebra gives its forms and its bracket; a system's step in those forms is the
    # system's (`_systems/fields.py`). A dependency upward that no import shows, such as a
    # method taking a `system` and reading its attributes, is what this catches.
    wrong = {
        str(f.relative_to(ROOT)): lines
        for f in sorted((PACKAGE / "_algebra").rglob("*.py"))
        if (lines := _mentions_system(f.read_text()))
    }
    assert not wrong, f"algebra modules that refer to a system (file: lines): {wrong}"


def test_the_system_check_sees_a_system():
    # what the algebra had before the step's fields moved to the system
    old = (
        "class A:\n"
        "    def local_field(self, system, x, dt, noise):\n"
        "        return self.bracket(x, system.step_gradient(x, dt, noise))\n"
    )
    assert _mentions_system(old) == [2, 3]
    assert _mentions_system('"""a system\'s step"""\nx = 1\n') == []


def test_every_system_has_a_noise_family():
    # The step's noise has one home, the noise family (`c=` is `ProportionalNoise`): no code
    # outside the families' module asks whether a system has one.
    import re

    pattern = re.compile(r"\bnoise is (not )?None\b")
    wrong = [
        f"{f.relative_to(ROOT)}:{i}"
        for f in sorted(PACKAGE.rglob("*.py"))
        if f != PACKAGE / "_systems" / "noise.py"
        for i, line in enumerate(f.read_text().splitlines(), 1)
        if pattern.search(line.split("#")[0])
    ]
    assert not wrong, f"code that asks whether a system has a noise family: {wrong}"
    assert pattern.search("if self.noise is None:") and pattern.search("x.noise is not None")


def test_no_private_name_of_the_driver_is_imported_from_outside():
    """The other subpackages reach the time loop through `_driver`'s documented interface
    (`run_ensemble`, `path_of_noise`, ...), never a private name of one of its modules."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if _unit(path) == "_driver":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and "_driver" in (node.module or "").split("."):
                found += [
                    f"{path.relative_to(ROOT)}: {node.module}.{a.name}"
                    for a in node.names
                    if a.name.startswith("_")
                ]
            elif isinstance(node, ast.Attribute) and node.attr.startswith("_"):
                base = node.value
                if (
                    isinstance(base, ast.Attribute)
                    and base.attr
                    in ("integrate", "plan", "retry", "splitting", "stream", "long_run", "failures")
                    and isinstance(base.value, ast.Name)
                    and base.value.id == "_driver"
                ):
                    found.append(f"{path.relative_to(ROOT)}: _driver.{base.attr}.{node.attr}")
    assert not found, "private names of _driver used outside it: " + "; ".join(found)


_DRIVER_CLASSES = {
    "AbstractDriver",
    "BrownianMotion",
    "OrnsteinUhlenbeck",
    "AbstractPath",
    "BrownianPath",
    "OrnsteinUhlenbeckPath",
    "AbstractDraws",
    "IndexedDraws",
    "StatefulDraws",
}


def test_no_code_asks_which_driver_it_holds():
    """Outside the drivers' module (`_brownian.py`), code asks a driver what it can do
    (`path`, `increments`, `carries_state`, `coarsens`), never which class it is: no
    `isinstance` names a driver, path or draws class."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.name == "_brownian.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if not (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Name)
                and node.func.id == "isinstance"
                and len(node.args) == 2
            ):
                continue
            names = {
                n.attr if isinstance(n, ast.Attribute) else getattr(n, "id", None)
                for n in ast.walk(node.args[1])
            }
            if names & _DRIVER_CLASSES:
                found.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not found, "isinstance on a driver class: " + ", ".join(found)
