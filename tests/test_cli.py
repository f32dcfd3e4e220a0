"""The ``navformer`` entry points: one-line errors for bad output paths, and ``run.sh``'s usage."""

import subprocess
from pathlib import Path

import pytest

from navformer_rl import cli

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(
    "argv",
    [
        ["collect", "e", "--out", "{file}"],
        ["demo", "--out", "{file}"],
        ["world-demo", "--out", "{file}"],
        ["evaluate", "--method", "vrw", "--protocol", "smoke", "--out", "{file}"],
    ],
)
def test_an_existing_file_as_output_folder_is_a_one_line_error(tmp_path, capsys, argv):
    existing = tmp_path / "afile"
    existing.write_text("keep me")
    with pytest.raises(SystemExit) as exit_info:
        cli.main([arg.format(file=existing) for arg in argv])
    assert exit_info.value.code == 2
    assert f"{existing} is a file; expected a folder" in capsys.readouterr().err
    assert existing.read_text() == "keep me"


def test_run_sh_without_arguments_prints_its_usage():
    done = subprocess.run(["bash", str(REPO / "run.sh")], capture_output=True, text=True, timeout=30)
    assert done.returncode == 0
    assert "./run.sh demo" in done.stdout and "./run.sh test" in done.stdout
    assert "set -euo" not in done.stdout
