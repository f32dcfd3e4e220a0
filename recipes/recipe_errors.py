"""The recipes' handling of user mistakes: one line and exit status 2, like the ``navformer`` command.

Shared by the hydra recipes (``recipes/{collect,navformer,evaluate}``): each script puts ``recipes/`` on
``sys.path`` and wraps its ``main`` in :func:`user_errors`. Hydra stays out of the ``navformer_rl`` library.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from hydra.core.hydra_config import HydraConfig

from navformer_rl.cli import USER_ERRORS

HYDRA_RECORDS = ("config.yaml", "hydra.yaml", "overrides.yaml")
"""What hydra writes into ``<run dir>/.hydra/`` before ``main`` runs."""


@contextmanager
def user_errors(recipe: str) -> Iterator[None]:
    """Report a mistake the user can fix as one line, ``<recipe>: error: <message>`` on stderr, and exit with
    status 2, like the ``navformer`` command (the same :data:`navformer_rl.cli.USER_ERRORS`; set
    ``NAVFORMER_DEBUG=1`` to get the traceback instead). A refused run leaves no folder behind: hydra's run
    folder is removed when it holds nothing but hydra's own records (:func:`remove_unused_run_dir`).
    Other errors and Ctrl-C pass through unchanged.
    """
    try:
        yield
    except USER_ERRORS as error:
        remove_unused_run_dir()
        if os.environ.get("NAVFORMER_DEBUG"):
            raise
        message = error.args[0] if isinstance(error, KeyError) and error.args else error
        print(f"{recipe}: error: {message}", file=sys.stderr)
        sys.exit(2)


def remove_unused_run_dir() -> None:
    """Remove the run folder hydra made for this launch if it holds only hydra's records (``.hydra/`` and an
    empty ``<job>.log``), then its parent folders below the launch directory that this leaves empty.

    A folder with anything else in it (results, checkpoints, a log with content) is kept untouched.
    """
    if not HydraConfig.initialized():
        return
    hydra_cfg = HydraConfig.get()
    run_dir = Path(hydra_cfg.runtime.output_dir).resolve()
    launch_dir = Path(hydra_cfg.runtime.cwd).resolve()
    if run_dir == launch_dir or run_dir in launch_dir.parents:  # hydra.run.dir=. : the user's own folder
        return
    records = {f"{hydra_cfg.job.name}.log": None}
    if hydra_cfg.output_subdir is not None:
        records[str(hydra_cfg.output_subdir)] = HYDRA_RECORDS
    try:
        entries = list(run_dir.iterdir())
        for entry in entries:
            if entry.name not in records or entry.is_symlink():
                return
            if records[entry.name] is None:  # the job log
                if not entry.is_file() or entry.stat().st_size:
                    return
            elif not entry.is_dir() or any(
                f.name not in HYDRA_RECORDS or f.is_symlink() or not f.is_file() for f in entry.iterdir()
            ):
                return
        for entry in entries:
            if entry.is_dir():
                for file in entry.iterdir():
                    file.unlink()
                entry.rmdir()
            else:
                entry.unlink()
        run_dir.rmdir()
        for parent in run_dir.parents:
            if parent == launch_dir or launch_dir not in parent.parents:
                break
            parent.rmdir()  # OSError when not empty: stop there
    except OSError:
        return
