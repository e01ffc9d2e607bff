"""The public API's boundary: every public module declares `__all__`, which names exactly its
public functions, classes and constants (not the modules it imports), and the package keeps
no deprecation shims (no release has had other names)."""

import ast
import importlib
import inspect
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


MAX_PARAMETERS = 12  # a public function's parameters at most: options that recur are objects


def _too_many_parameters(module):
    """`name: count` of the public functions and public classes' constructors and methods
    of `module` with more than `MAX_PARAMETERS` parameters (`self` not counted)."""
    out = {}
    for name in module.__all__:
        value = getattr(module, name)
        found = []
        if isinstance(value, types.FunctionType):
            found.append((name, value, 0))
        elif isinstance(value, type) and value.__module__.startswith("slps_jax"):
            found.append((name, value, 0))
            for attr, fn in vars(value).items():
                if isinstance(fn, types.FunctionType) and not attr.startswith("_"):
                    found.append((f"{name}.{attr}", fn, 1))
        for label, fn, bound in found:
            try:
                count = len(inspect.signature(fn).parameters) - bound
            except (TypeError, ValueError):  # (a class without an inspectable constructor)
                continue
            if count > MAX_PARAMETERS:
                out[label] = count
    return out


@pytest.mark.parametrize("name", PUBLIC_MODULES)
def test_no_public_function_takes_more_than_twelve_parameters(name):
    too_many = _too_many_parameters(importlib.import_module(name))
    assert not too_many, f"{name}: more than {MAX_PARAMETERS} parameters: {too_many}"


def test_the_parameter_check_sees_a_long_signature():
    module = types.ModuleType("fake")
    exec("def long(" + ", ".join(f"a{i}" for i in range(13)) + "): pass", vars(module))
    exec("def short(a, b): pass", vars(module))
    module.__all__ = ["long", "short"]
    assert _too_many_parameters(module) == {"long": 13}


# A Module subclassed by others although concrete, and why (the one left to split)
def _modules_of_the_package():
    import pkgutil

    import equinox as eqx

    import slps_jax

    names = [m.name for m in pkgutil.walk_packages(slps_jax.__path__, "slps_jax.")]
    classes = set()
    for module in [slps_jax, *map(importlib.import_module, names)]:
        for value in vars(module).values():
            if (
                isinstance(value, type)
                and issubclass(value, eqx.Module)
                and value.__module__.startswith("slps_jax")
            ):
                classes.add(value)
    return classes


def test_every_module_is_abstract_or_final():
    """equinox's rule: a Module that others subclass is abstract (its name starts with
    `Abstract`, and it declares what its subclasses give as abstract methods, `AbstractVar`s
    or `AbstractClassVar`s), and a concrete one is final (nothing subclasses it); no
    abstract name on a concrete class."""
    import inspect

    classes = _modules_of_the_package()
    wrong = []
    for cls in sorted(classes, key=lambda c: c.__qualname__):
        named = cls.__name__.lstrip("_").startswith("Abstract")
        subclassed = any(other is not cls and issubclass(other, cls) for other in classes)
        if subclassed and not named:
            wrong.append(f"{cls.__name__}: concrete, subclassed")
        if named and not inspect.isabstract(cls) and not _has_abstract_vars(cls):
            wrong.append(f"{cls.__name__}: named abstract, declares nothing abstract")
    assert not wrong, "; ".join(wrong)
    assert "AbstractLiePoissonSystem" in {c.__name__ for c in classes}


def _has_abstract_vars(cls):
    import equinox as eqx

    return any(
        isinstance(hint, str)
        and ("AbstractVar" in hint or "AbstractClassVar" in hint)
        or getattr(hint, "__origin__", None) in (eqx.AbstractVar, eqx.AbstractClassVar)
        for klass in cls.__mro__
        for hint in vars(klass).get("__annotations__", {}).values()
    )
