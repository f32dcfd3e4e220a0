"""The simulated world and the envs (paper §III, §V, §VII); see ``docs/world.md``.

Modules (imported explicitly; importing this package starts no pybullet client):
``world`` (seeded generator, ``WorldSpec``), ``occupancy`` (``OccupancyMap``, shortest paths), ``robots``
(``JACKAL``, ``TURTLEBOT3``), ``sim`` (``Simulator``), ``target_image``, ``topdown``, ``obstacle_policy``,
``target_nav`` (gymnasium ``TargetNavEnv``, id ``navformer_rl/TargetNav-v0``), ``torchrl_target_nav``
(``make_torchrl_target_nav_env``), ``multi_robot`` (TorchRL ``MultiRobotNavEnv``), ``policy_transforms``
(``add_policy_transforms``: the ``InitTracker`` / ``StepCounter`` a policy needs; ``ToUint8Image``), ``demo``
(``run_world_demo``), ``checks`` (argument checks shared by all of them: ValueError naming the bad value and
what was expected).
"""
