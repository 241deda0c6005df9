"""The package layout holds: libraries do not reach into the daemon, nothing but tools uses the demo module,
and no file cites a document outside the repository."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
LIBRARIES = ("pivot", "maps", "gimbal", "bus")
APPLICATION = ("pivotd.cli", "pivotd.config", "pivotd.daemon", "pivotd.sim")


def imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), str(path))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
    return out


@pytest.mark.parametrize("library", LIBRARIES)
def test_libraries_do_not_import_the_application_layers(library):
    offenders = {
        f"{path.relative_to(REPO)}: {module}"
        for path in sorted((REPO / "pivotd" / library).rglob("*.py"))
        for module in imported_modules(path)
        if module.startswith(APPLICATION)
    }
    assert not offenders


def test_only_the_demo_wrapper_imports_the_demo_module():
    users = {
        str(path.relative_to(REPO))
        for path in [*REPO.joinpath("pivotd").rglob("*.py"), *REPO.joinpath("tests").rglob("*.py"),
                     REPO / "tools" / "demo.py"]
        if "pivotd.sim.demo" in imported_modules(path)
    }
    assert users == {"tools/demo.py"}


def test_no_file_cites_a_design_document_outside_the_repository():
    cited = re.compile(r"DESIGN(\.md)? ?§|\.\./shared")
    files = [p for ext in ("*.py", "*.md", "*.yaml", "*.service") for p in REPO.rglob(ext)
             if ".venv" not in p.parts and "build" not in p.parts]
    offenders = [str(p.relative_to(REPO)) for p in files if p != Path(__file__) and cited.search(p.read_text())]
    assert not offenders
