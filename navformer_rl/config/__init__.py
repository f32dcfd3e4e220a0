"""Packaged configurations: ``train.yaml``, read by ``navformer train`` and composed by the hydra recipe
``recipes/navformer`` (its ``config.yaml`` puts ``pkg://navformer_rl.config`` on hydra's search path)."""
