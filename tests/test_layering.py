"""Imports run downhill: no library module imports the command-line package, and the model package imports
neither the pretrained registry nor the training package (loading weights by name is one floor up, in
``navformer_rl.pretrained``). Function-level imports count too."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "navformer_rl"


def imported(path: Path) -> set[str]:
    """The absolute module names ``path`` imports anywhere (``from x import y`` gives ``x`` and ``x.y``)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return names


def offenders(files, forbidden: tuple[str, ...]) -> list[str]:
    return [
        f"{path.relative_to(PACKAGE)}: {name}"
        for path in files
        for name in sorted(imported(path))
        if any(name == f or name.startswith(f + ".") for f in forbidden)
    ]


def test_no_library_module_imports_the_command_line_package():
    entry_points = {PACKAGE / "__main__.py"}
    library = [p for p in sorted(PACKAGE.rglob("*.py")) if "cli" not in p.relative_to(PACKAGE).parts[:1]]
    assert offenders([p for p in library if p not in entry_points], ("navformer_rl.cli",)) == []


def test_the_model_package_knows_neither_the_registry_nor_the_training_package():
    modules = sorted((PACKAGE / "modules").rglob("*.py"))
    assert modules
    assert offenders(modules, ("navformer_rl.pretrained", "navformer_rl.training")) == []
