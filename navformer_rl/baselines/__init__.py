"""Policies the evaluation harness can run besides NavFormer: VRW, DT, the privileged FCA and the D_e
exploration expert (``FrontierPolicy``).

Every policy is a ``TensorDictModuleBase`` over the ``MultiRobotNavEnv`` tensordict that writes
``("agents", "action")`` float32 ``[A, 2]``; the harness calls ``bind(env, seed)`` after every reset when
the policy has it (episode seed, and for privileged policies access to ``env.world`` / ``env.simulator``).
"""

from navformer_rl.baselines.dt import load_dt_policy
from navformer_rl.baselines.expert_policy import ExpertPolicy
from navformer_rl.baselines.fca import FCAPolicy
from navformer_rl.baselines.frontier import FrontierPolicy
from navformer_rl.baselines.navformer import load_navformer_policy
from navformer_rl.baselines.random_walk import RandomWalkPolicy

__all__ = [
    "ExpertPolicy",
    "FCAPolicy",
    "FrontierPolicy",
    "RandomWalkPolicy",
    "load_dt_policy",
    "load_navformer_policy",
]
