"""The user docs run as written: every fenced ``python`` block of the documents below, and the ``Examples:``
of the pieces users compose.

Blocks run in document order, each in its own namespace (so each needs its own imports) and in one scratch
folder per document (so a block may read the files an earlier one wrote, e.g. ``data/e``). A block that
needs real data or hours is marked on the line before its fence with ``<!-- doc-test: skip (REASON) -->``
and reported as skipped with that reason.
"""

from __future__ import annotations

import doctest
import importlib
import io
import re
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCUMENTS = ("README.md", "docs/datasets.md", "docs/model.md", "docs/training.md", "docs/pretrained.md")
SKIP_MARK = re.compile(r"<!--\s*doc-test:\s*skip\s*\((?P<reason>.+)\)\s*-->")
EXAMPLES = (
    "navformer_rl.data.samplers.TrajectorySampler",
    "navformer_rl.data.samplers.TrajectoryBatcher",
    "navformer_rl.data.cross_task.CrossTaskReplayBuffer",
    "navformer_rl.modules.actors.make_navformer_actor",
    "navformer_rl.objectives.dt_loss.ActionMSELoss",
    "navformer_rl.objectives.byol.BYOLLoss",
    "navformer_rl.envs.policy_transforms.add_policy_transforms",
    "navformer_rl.envs.policy_transforms.ToUint8Image",
)


def python_blocks(document: str) -> list[tuple[int, str, str | None]]:
    """``(line of the fence, code, skip reason or None)`` for each fenced python block of ``document``."""
    lines = (ROOT / document).read_text().splitlines()
    blocks, i = [], 0
    while i < len(lines):
        fence = lines[i].strip()
        if fence == "```python":
            indent = len(lines[i]) - len(lines[i].lstrip())
            end = next(j for j in range(i + 1, len(lines)) if lines[j].strip() == "```")
            code = "\n".join(line[indent:] for line in lines[i + 1 : end])
            mark = SKIP_MARK.search(lines[i - 1]) if i else None
            blocks.append((i + 1, code, mark.group("reason") if mark else None))
            i = end
        i += 1
    return blocks


BLOCKS = [(document, *block) for document in DOCUMENTS for block in python_blocks(document)]


def test_every_document_was_read():
    """Guards the extraction itself: the documents with snippets are found, and each skip has its reason."""
    found = {document for document, *_ in BLOCKS}
    assert {"README.md", "docs/datasets.md", "docs/model.md", "docs/pretrained.md"} <= found
    skipped = [reason for *_, reason in BLOCKS if reason is not None]
    assert 0 < len(skipped) <= 3 and all(reason.strip() for reason in skipped)


@pytest.fixture(scope="module")
def scratch(tmp_path_factory):
    """One scratch folder per document, and the blocks already run there."""
    folders: dict[str, Path] = {}
    done: set[tuple[str, int]] = set()

    def folder(document: str) -> Path:
        if document not in folders:
            folders[document] = tmp_path_factory.mktemp(Path(document).stem)
        return folders[document]

    return folder, done


def run_block(document: str, line: int, code: str) -> None:
    namespace = {"__name__": f"doc_snippet_{Path(document).stem}_{line}"}
    exec(compile(code, f"{document}:{line}", "exec"), namespace)


@pytest.mark.parametrize(
    ("document", "line", "code", "skip"), BLOCKS, ids=[f"{d}:{line}" for d, line, *_ in BLOCKS]
)
def test_python_block_runs_as_written(document, line, code, skip, scratch, monkeypatch, capsys):
    if skip is not None:
        pytest.skip(skip)
    folder, done = scratch
    monkeypatch.chdir(folder(document))
    monkeypatch.setenv("RL_LOGGING_LEVEL", "WARNING")
    # the blocks before this one in the same document first (when this block is run alone)
    for earlier_line, earlier_code, reason in python_blocks(document):
        if earlier_line >= line:
            break
        if reason is None and (document, earlier_line) not in done:
            run_block(document, earlier_line, earlier_code)
            done.add((document, earlier_line))
    run_block(document, line, code)
    done.add((document, line))


@pytest.mark.parametrize("name", EXAMPLES)
def test_docstring_examples_run(name, tmp_path, monkeypatch):
    module_name, _, attribute = name.rpartition(".")
    target = getattr(importlib.import_module(module_name), attribute)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # the examples' mkdtemp() folders
    tests = doctest.DocTestFinder(recurse=False).find(target, name, globs={})
    out = io.StringIO()
    runner = doctest.DocTestRunner(optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    for test in tests:
        runner.run(test, out=out.write)
    results = runner.summarize(verbose=False)
    assert results.attempted > 0, f"{name} has no Examples"
    assert results.failed == 0, out.getvalue()
