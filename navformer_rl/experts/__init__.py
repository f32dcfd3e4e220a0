"""Expert planners that generate the offline datasets and the privileged FCA baseline.

Pure numpy planners (no simulator needed): :mod:`astar`, :mod:`grid`, :mod:`mapping`, :mod:`frontier`,
:mod:`dwa`, :mod:`orca`, :mod:`nh_orca`. Simulator-driven experts live in :mod:`policies` (imported
lazily by callers: ``from navformer_rl.experts.policies import ExplorationExpert``).
"""
