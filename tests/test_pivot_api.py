"""The optimizer's public API: every module of pivotd/pivot declares ``__all__``, and code outside the package
(pivotd/, tools/) imports only its public modules and the names they declare."""

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PIVOT = ROOT / "pivotd" / "pivot"
MODULES = sorted(p.stem for p in PIVOT.glob("*.py") if p.stem != "__init__")
NO_ALL_YET: set[str] = set()  # no __all__ yet (its exports: the names without a leading underscore); strict xfail


def public_names(module: str) -> set[str]:
    """The names ``module`` (a name in pivotd.pivot) exports: its ``__all__``, or, without one, what
    ``from module import *`` would take (its names without a leading underscore)."""
    mod = importlib.import_module(f"pivotd.pivot.{module}")
    names = getattr(mod, "__all__", None)
    return set(names) if names is not None else {n for n in vars(mod) if not n.startswith("_")}


def violations(source: str, filename: str) -> list[str]:
    """Imports in ``source`` that reach past the optimizer's API: a private module (name starting with ``_``),
    a name outside the module's exports (also through ``module.name`` on an imported module), a star import."""
    tree = ast.parse(source, filename=filename)
    found: list[str] = []
    aliases: dict[str, str] = {}  # local name -> module of pivotd.pivot

    def module_ok(module: str, line: int) -> bool:
        if module.startswith("_") or module not in MODULES:
            found.append(f"{filename}:{line}: imports private or unknown module pivotd.pivot.{module}")
            return False
        return True

    def name_ok(module: str, name: str, line: int) -> None:
        if name not in public_names(module):
            found.append(f"{filename}:{line}: pivotd.pivot.{module}.{name} is not in the module's __all__")

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("pivotd.pivot."):
                    module = a.name.split(".")[2]
                    if module_ok(module, node.lineno) and a.asname:
                        aliases[a.asname] = module
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            parts = node.module.split(".")
            if node.module in ("pivotd", "pivotd.pivot"):  # from pivotd.pivot import view (or from pivotd import pivot)
                for a in node.names:
                    if node.module == "pivotd.pivot" and module_ok(a.name, node.lineno):
                        aliases[a.asname or a.name] = a.name
            elif parts[:2] == ["pivotd", "pivot"] and module_ok(parts[2], node.lineno):
                for a in node.names:
                    if a.name == "*":
                        found.append(f"{filename}:{node.lineno}: star import from {node.module}")
                    else:
                        name_ok(parts[2], a.name, node.lineno)
    for node in ast.walk(tree):  # module.name on a module imported as a name
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases:
            name_ok(aliases[node.value.id], node.attr, node.lineno)
    return found


@pytest.mark.parametrize("module", [
    pytest.param(m, marks=pytest.mark.xfail(strict=True, reason=f"pivotd/pivot/{m}.py declares no __all__ yet"))
    if m in NO_ALL_YET else m for m in MODULES])
def test_every_optimizer_module_declares_what_it_exports(module):
    mod = importlib.import_module(f"pivotd.pivot.{module}")
    assert isinstance(getattr(mod, "__all__", None), list), f"pivotd/pivot/{module}.py declares no __all__"
    missing = [n for n in mod.__all__ if not hasattr(mod, n)]
    assert not missing, f"pivotd/pivot/{module}.py lists undefined names in __all__: {missing}"
    assert all(not n.startswith("_") for n in mod.__all__), mod.__all__
    assert len(set(mod.__all__)) == len(mod.__all__), mod.__all__


def test_code_outside_the_optimizer_uses_only_its_public_api():
    sources = [p for base in ("pivotd", "tools") for p in sorted((ROOT / base).rglob("*.py")) if PIVOT not in p.parents]
    assert len(sources) > 50  # the walk found the daemon, the CLI, the benches and the tools
    found = [v for p in sources for v in violations(p.read_text(encoding="utf-8"), str(p.relative_to(ROOT)))]
    assert not found, "\n".join(found)


@pytest.mark.parametrize("source, what", [
    ("from pivotd.pivot._checks import half_angle", "private or unknown module pivotd.pivot._checks"),
    ("from pivotd.pivot import _ascent", "private or unknown module pivotd.pivot._ascent"),
    ("import pivotd.pivot._ascent as a", "private or unknown module pivotd.pivot._ascent"),
    ("from pivotd.pivot.view import _frame", "pivotd.pivot.view._frame is not in"),
    ("from pivotd.pivot.polish import tangent_basis", "pivotd.pivot.polish.tangent_basis is not in"),
    ("from pivotd.pivot import view\nview._refine", "pivotd.pivot.view._refine is not in"),
    ("import pivotd.pivot.view as v\nv.fibonacci_sphere(4)", "pivotd.pivot.view.fibonacci_sphere is not in"),
    ("from pivotd.pivot.lattice import *", "star import"),
])
def test_the_check_names_each_kind_of_breach(source, what):
    found = violations(source, "x.py")
    assert len(found) == 1 and what in found[0], found


def test_the_check_accepts_public_imports():
    ok = ("from pivotd.pivot.view import ViewOptions, optimize_view\nfrom pivotd.pivot import lattice\n"
          "lattice.sphere_grid(2.0)\nimport pivotd.pivot.steps as st\nst.step_angles\n"
          "from pivotd.pivot.joint_dp import JointGrid\nfrom pivotd.geometry import tangent_basis\n")
    assert violations(ok, "x.py") == []
