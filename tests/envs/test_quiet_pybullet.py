"""pybullet's "build time" line (printed by its C code on import, in every worker process) is silenced."""

import subprocess
import sys


def test_importing_pybullet_prints_nothing_and_output_still_flows():
    script = (
        "import sys\n"
        "from navformer_rl.envs.sim import import_pybullet\n"
        "p = import_pybullet()\n"
        "assert import_pybullet() is p and p.connect(p.DIRECT) >= 0\n"
        "print('out'); print('err', file=sys.stderr)\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert (done.stdout, done.stderr) == ("out\n", "err\n")
