"""``navformer export minari``: the command writes a loadable dataset; user errors are one line (status 2)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from navformer_rl import cli
from navformer_rl.data import open_dataset

REPO = Path(__file__).resolve().parents[2]


def test_export_minari_writes_a_loadable_dataset(source_datasets, minari_path, capsys):
    minari = pytest.importorskip("minari")  # the optional extra navformer_rl[minari]
    argv = [
        "export",
        "minari",
        str(source_datasets["e"]),
        "--id",
        "navformer/e-v0",
        "--root",
        str(minari_path),
    ]
    assert cli.main([*argv, "--no-progress", "--chunk-steps", "4"]) == 0
    assert capsys.readouterr().out.strip() == f"navformer/e-v0: {minari_path / 'navformer' / 'e-v0'}"
    assert minari.load_dataset("navformer/e-v0").total_steps == len(open_dataset(source_datasets["e"]))


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("bad_id", "Minari dataset id 'e-v0' is not NAMESPACE/NAME-vN"),
        ("missing", "dataset folder {missing} does not exist"),
        ("ssl", "{ssl} is a D_ssl dataset: image pairs (o^s, o^d), not trajectories"),
        ("exists", "Minari dataset navformer/e-v0 already exists in"),
        ("no_minari", "needs minari and h5py, which are not installed"),
    ],
)
def test_user_errors_are_one_line(source_datasets, minari_path, tmp_path, capsys, monkeypatch, case, message):
    if case == "exists":
        pytest.importorskip("minari")
    dataset, dataset_id = source_datasets["e"], "navformer/e-v0"
    if case == "bad_id":
        dataset_id = "e-v0"
    elif case == "missing":
        dataset = tmp_path / "nowhere"
    elif case == "ssl":
        dataset = source_datasets["ssl"]
    elif case == "exists":
        cli.main(
            [
                "export",
                "minari",
                str(dataset),
                "--id",
                dataset_id,
                "--root",
                str(minari_path),
                "--no-progress",
            ]
        )
        capsys.readouterr()
    elif case == "no_minari":
        monkeypatch.setitem(sys.modules, "minari", None)
    code = cli.main(["export", "minari", str(dataset), "--id", dataset_id, "--root", str(minari_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert err[0].startswith("navformer export: error: ")
    assert message.format(missing=tmp_path / "nowhere", ssl=source_datasets["ssl"]) in err[0]
    if case == "no_minari":
        assert err[0].endswith('pip install "navformer_rl[minari]"')
    if case != "exists":
        assert not (minari_path / "navformer").exists()


def test_help_and_a_bad_id_import_neither_minari_nor_torch():
    script = (
        "import contextlib, io, sys\n"
        "import navformer_rl.cli as cli\n"
        "for argv in (['export', '--help'], ['export', 'minari', '--help'],\n"
        "             ['export', 'minari', 'x', '--id', 'bad']):\n"
        "    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):\n"
        "        try:\n"
        "            cli.main(argv)\n"
        "        except SystemExit:\n"
        "            pass\n"
        "print(sorted(m for m in ('torch', 'torchrl', 'tensordict', 'minari', 'h5py') if m in sys.modules))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, cwd=REPO
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"
