"""The ``navformer`` entry points: one-line errors for bad output paths, and ``run.sh``'s usage."""

import os
import subprocess
import sys
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


def test_help_and_argument_errors_do_not_import_torch():
    """``navformer --help``, ``navformer train --help``, argument errors and bad training settings answer
    before torch loads."""
    script = (
        "import contextlib, io, sys\n"
        "import navformer_rl.cli as cli\n"
        "for argv in (['--help'], ['train', '--help'], ['evaluate', '--help'], "
        "['collect', 'e', '--n', '0'],\n"
        "             ['train', 'ablation=bogus'], ['train', 'model.d_embed=x'], "
        "['train', '--print-config']):\n"
        "    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):\n"
        "        try:\n"
        "            cli.main(argv)\n"
        "        except SystemExit:\n"
        "            pass\n"
        "print(sorted(name for name in ('torch', 'torchrl', 'tensordict', 'pybullet') "
        "if name in sys.modules))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, cwd=REPO
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


@pytest.mark.parametrize(
    ("argv", "flag"),
    [
        (["evaluate", "--method", "vrw", "--protocol", "smoke", "--trials-per-setup", "-3"],
         "--trials-per-setup"),
        (["evaluate", "--method", "vrw", "--protocol", "smoke", "--trials-per-world", "0"],
         "--trials-per-world"),
        (["evaluate", "--method", "vrw", "--protocol", "smoke", "--max-steps", "0"], "--max-steps"),
        (["evaluate", "--method", "vrw", "--protocol", "smoke", "--workers", "0"], "--workers"),
        (["evaluate", "--method", "vrw", "--protocol", "smoke", "--videos", "-1"], "--videos"),
        (["evaluate", "--method", "vrw", "--protocol", "smoke", "--maps", "-1"], "--maps"),
        (["evaluate", "make-episodes", "--protocol", "smoke", "--trials-per-setup", "-3", "--out", "x"],
         "--trials-per-setup"),
        (["collect", "e", "--out", "{tmp}", "--workers", "0"], "--workers"),
        (["collect", "e", "--out", "{tmp}", "--n", "0"], "--n"),
        (["collect", "e", "--out", "{tmp}", "--action-noise", "2"], "--action-noise"),
        (["validate", "--checkpoint", "x", "--batch-trajs", "0"], "--batch-trajs"),
    ],
)  # fmt: skip
def test_bad_values_are_reported_by_their_flag(tmp_path, capsys, argv, flag):
    with pytest.raises(SystemExit) as exit_info:
        cli.main([arg.format(tmp=tmp_path / "out") for arg in argv])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert f"argument {flag}: expected" in err
    assert "_" not in err.split(":", 2)[-1]  # no internal names such as trials_per_setup


def test_unknown_setups_are_reported_by_the_flag(tmp_path, capsys):
    argv = ["evaluate", "--method", "vrw", "--protocol", "smoke", "--setups", "9m-1r", "--out", str(tmp_path)]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "--setups '9m-1r': expected setups of --protocol smoke" in err and "7.5m-2r" in err


def test_run_sh_help_lists_every_navformer_command():
    done = subprocess.run(
        ["bash", str(REPO / "run.sh"), "--help"], capture_output=True, text=True, timeout=30
    )
    assert done.returncode == 0
    commands = cli.build_parser()._subparsers._group_actions[0].choices
    listed = {line.split()[0] for line in done.stdout.splitlines() if line.startswith("  ") and line.split()}
    assert set(commands) - {"demo"} <= listed
    assert "./run.sh demo" in done.stdout


FAKE_PYTHON = """#!/bin/bash
# stands in for `python3 -m venv DIR`: a venv whose tools only record how they were called
mkdir -p "$3/bin"
for tool in python pip navformer; do
    printf '#!/bin/bash\\necho "%s $*" >> "%s/calls.txt"\\n' "$tool" "$3" > "$3/bin/$tool"
    chmod +x "$3/bin/$tool"
done
"""


def test_run_sh_says_what_each_install_step_does(tmp_path):
    fake_python = tmp_path / "python3"
    fake_python.write_text(FAKE_PYTHON)
    fake_python.chmod(0o755)
    venv = tmp_path / "venv"
    env = {**os.environ, "NAVFORMER_VENV": str(venv), "PYTHON": str(fake_python)}
    run = ["bash", str(REPO / "run.sh"), "collect", "--help"]
    first = subprocess.run(run, capture_output=True, text=True, timeout=30, env=env)
    assert first.returncode == 0, first.stderr
    steps = [line for line in first.stderr.splitlines() if line.startswith("run.sh: ")]
    assert [line.split(":")[1].split()[0] for line in steps] == [
        "creating",
        "installing",
        "installing",
        "installed;",
    ]
    assert "torch" in steps[1] and "navformer_rl" in steps[2]
    calls = (venv / "calls.txt").read_text().splitlines()
    assert calls[0].startswith("pip install --quiet torch==")
    assert calls[1].startswith(
        f"pip install --quiet -c {REPO / 'constraints.txt'} -e "
    )  # the tested versions
    assert calls[2] == "navformer collect --help"
    again = subprocess.run(run, capture_output=True, text=True, timeout=30, env=env)
    assert again.stderr == ""  # installed: nothing to say
