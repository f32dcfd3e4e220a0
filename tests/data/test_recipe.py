"""The hydra collection recipe (a subprocess, like TorchRL's sota smoke tests),
and what the three recipes share."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

RECIPES = Path(__file__).resolve().parents[2] / "recipes"


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (["kind=ssl_pairs"], "unknown dataset kind 'ssl_pairs'"),
        (["kind=e", "workers=-1"], "workers must be >= 1, got -1"),
    ],
)
def test_recipe_reports_a_mistake_in_one_line_and_leaves_no_folder(tmp_path, overrides, message):
    """Like `navformer collect`: one line, exit status 2, no traceback; neither hydra's run folder
    (outputs/collect/<time>/, made before the script runs) nor the dataset folder is left behind."""
    done = subprocess.run(
        [sys.executable, str(RECIPES / "collect" / "collect.py"), *overrides, "out=data", "progress=false"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
        timeout=300,
    )
    assert done.returncode == 2, done.stderr[-2000:]
    assert "Traceback" not in done.stderr
    assert len(done.stderr.splitlines()) == 1 and done.stderr.startswith("collect.py: error: ")
    assert message in done.stderr
    assert list(tmp_path.iterdir()) == []


def test_user_errors_exits_with_one_line_and_passes_other_errors(capsys, monkeypatch):
    """The recipes' shared handler (recipes/recipe_errors.py): a user mistake -> one line on stderr and status
    2; anything else (a bug) keeps its traceback; NAVFORMER_DEBUG=1 re-raises the mistake too."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("recipe_errors", RECIPES / "recipe_errors.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    user_errors = module.user_errors

    monkeypatch.delenv("NAVFORMER_DEBUG", raising=False)
    with pytest.raises(SystemExit) as exit_info, user_errors("demo.py"):
        raise ValueError("workers must be >= 1, got -1")
    assert exit_info.value.code == 2
    assert capsys.readouterr().err == "demo.py: error: workers must be >= 1, got -1\n"
    with pytest.raises(ZeroDivisionError), user_errors("demo.py"):
        raise ZeroDivisionError  # not a user error
    monkeypatch.setenv("NAVFORMER_DEBUG", "1")
    with pytest.raises(ValueError), user_errors("demo.py"):
        raise ValueError("shown with its traceback")


def test_the_library_imports_neither_hydra_nor_the_recipes():
    """Hydra and recipes/ (recipe_errors.py included) stay on the recipes' side of the package."""
    import ast

    package = RECIPES.parent / "navformer_rl"
    offenders = []
    for path in sorted(package.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0:
                names = [node.module or ""]
            else:
                continue
            top = {name.split(".")[0] for name in names}
            offenders += [
                f"{path.relative_to(package)}: {name}" for name in top & {"hydra", "recipes", "recipe_errors"}
            ]
    assert offenders == []
