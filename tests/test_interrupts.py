"""Ctrl-C with process pools: workers start with SIGINT blocked, leave quietly, the parent reports once."""

import os
import signal
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import pytest

from navformer_rl.utils.interrupts import exit_on_sigint, spawn_context

REPO = Path(__file__).resolve().parents[1]


def test_workers_start_with_sigint_blocked_and_the_parent_keeps_its_own():
    before = signal.pthread_sigmask(signal.SIG_BLOCK, [])
    with ProcessPoolExecutor(1, mp_context=spawn_context()) as pool:
        assert signal.SIGINT in pool.submit(signal.pthread_sigmask, signal.SIG_BLOCK, []).result(timeout=60)
    assert signal.pthread_sigmask(signal.SIG_BLOCK, []) == before


def test_an_initialised_worker_ends_silently_on_sigint(capfd):
    pool = ProcessPoolExecutor(1, mp_context=spawn_context(), initializer=exit_on_sigint)
    try:
        assert pool.submit(os.getpid).result(timeout=60) > 0  # started and initialised
        (worker,) = pool._processes.values()
        sleeping = pool.submit(time.sleep, 60)
        time.sleep(0.5)
        os.kill(worker.pid, signal.SIGINT)
        with pytest.raises(BrokenProcessPool):
            sleeping.result(timeout=30)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    # the pool's own thread reaps its workers: joining one here as well races it for the exit status
    assert worker.exitcode == 128 + signal.SIGINT
    assert capfd.readouterr().err == ""


def _workers_importing_torch(pid: int) -> int:
    """How many ``spawn`` children of ``pid`` have started loading torch (their start-up's long import)."""
    count = 0
    for entry in Path("/proc").iterdir():
        try:
            if (
                not entry.name.isdigit()
                or int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1]) != pid
            ):
                continue
            if (
                b"spawn_main" in (entry / "cmdline").read_bytes()
                and "libtorch" in (entry / "maps").read_text()
            ):
                count += 1
        except (OSError, IndexError, ValueError):
            continue
    return count


def _default_sigint() -> None:
    """In the child before ``exec``: SIGINT back to its default action. A suite run as a background job
    (``nohup pytest &``, a CI runner) ignores SIGINT, the child would inherit that, and Python leaves an
    inherited ignored SIGINT ignored: Ctrl-C would not reach the command under test."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="finds the worker processes through /proc")
def test_ctrl_c_while_evaluation_workers_start_prints_one_line(tmp_path):
    """SIGINT to the whole process group (as Ctrl-C sends it) while the two workers are still importing torch:
    no worker traceback, one line from the parent."""
    command = [sys.executable, "-m", "navformer_rl.cli", "evaluate", "--method", "vrw", "--protocol", "smoke"]
    command += ["--trials-per-setup", "2", "--trials-per-world", "1", "--workers", "2"]
    command += ["--out", str(tmp_path / "vrw"), "--no-progress"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    process = subprocess.Popen(
        command, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True, preexec_fn=_default_sigint,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while _workers_importing_torch(process.pid) < 2 and process.poll() is None:
            assert time.monotonic() < deadline, "the workers did not start"
            time.sleep(0.05)
        os.killpg(process.pid, signal.SIGINT)
        _, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
    assert process.returncode == 130, err
    assert err.strip().splitlines() == [
        "navformer evaluate: interrupted (finished work is kept; rerun to resume)"
    ]


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="watches the process's memory maps through /proc")
def test_sigterm_takes_the_ctrl_c_path_with_status_143(tmp_path):
    """SIGTERM (a job scheduler's stop) runs the same clean-up as Ctrl-C and says so in one line."""
    command = [sys.executable, "-m", "navformer_rl.cli", "evaluate", "--method", "vrw", "--protocol", "smoke"]
    command += ["--trials-per-setup", "2", "--trials-per-world", "1", "--workers", "1"]
    command += ["--out", str(tmp_path / "vrw"), "--no-progress"]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    process = subprocess.Popen(
        command, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        deadline = time.monotonic() + 120
        maps = Path(f"/proc/{process.pid}/maps")
        # torch is imported when the subcommand runs, after the handler is installed
        while process.poll() is None and "libtorch" not in maps.read_text():
            assert time.monotonic() < deadline, "the command did not start"
            time.sleep(0.05)
        process.send_signal(signal.SIGTERM)
        _, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 143, err
    assert err.strip().splitlines() == [
        "navformer evaluate: terminated (finished work is kept; rerun to resume)"
    ]
