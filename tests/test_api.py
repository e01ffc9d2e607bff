"""The public API's boundary: every public module declares `__all__`, which names exactly its
public functions, classes and constants (not the modules it imports), and the package keeps
no deprecation shims (no release has had other names)."""

import ast
import importlib
import pathlib
import types

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "slps_jax"
PUBLIC_MODULES = ["slps_jax", "slps_jax.zeitlin", "slps_jax.so3", "slps_jax.sphere"]


def _public_modules_on_disk():
    """The package's modules whose path has no part starting with an underscore."""
    found = {"slps_jax"}
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE).with_suffix("")
        if not any(part.startswith("_") for part in rel.parts):
            found.add(".".join(["slps_jax", *rel.parts]))
    return found


def test_the_public_modules_are_those_listed():
    assert _public_modules_on_disk() == set(PUBLIC_MODULES)


def _leaked(module):
    """Public names of `module` that `__all__` leaves out, other than imported modules and
    `from __future__` features."""
    out = []
    for name, value in vars(module).items():
        if name.startswith("_") or name in module.__all__ or name == "annotations":
            continue
        if isinstance(value, types.ModuleType) and value.__name__ != f"{module.__name__}.{name}":
            continue  # (numpy as np, ...: not part of the API, and `import *` skips them)
        out.append(name)
    return out


@pytest.mark.parametrize("name", PUBLIC_MODULES)
def test_every_public_module_declares_all(name):
    module = importlib.import_module(name)
    assert isinstance(module.__all__, list | tuple)
    assert len(set(module.__all__)) == len(module.__all__), "a name listed twice"
    missing = [n for n in module.__all__ if not hasattr(module, n)]
    assert not missing, f"{name}.__all__ names what the module lacks: {missing}"
    assert not _leaked(module), f"{name} has public names outside __all__: {_leaked(module)}"
    assert not [n for n in module.__all__ if n.startswith("_")]


def test_the_boundary_check_sees_a_leak():
    module = types.ModuleType("fake")
    module.__all__ = ["kept"]
    module.kept = 1
    module.extra = 2
    module.np = importlib.import_module("numpy")  # (an imported module: allowed)
    assert _leaked(module) == ["extra"]


def _deprecations(source):
    """Lines of `source` that name `DeprecationWarning` or `FutureWarning`."""
    return [
        node.lineno
        for node in ast.walk(ast.parse(source))
        if isinstance(node, ast.Name) and node.id in ("DeprecationWarning", "FutureWarning")
    ]


def test_no_deprecation_shims():
    found = {
        str(path.relative_to(ROOT)): lines
        for path in PACKAGE.rglob("*.py")
        if (lines := _deprecations(path.read_text()))
    }
    assert not found, f"deprecation warnings issued at {found}"


def test_the_shim_check_sees_a_shim():
    assert _deprecations("import warnings\nwarnings.warn('old', DeprecationWarning)\n") == [2]
