"""NavFormer cross-task training recipe (paper §VI): ``python recipes/navformer/navformer.py [key=value ...]``.

Per iteration: a batch of 25 D_e or 150 D_ca trajectories (alternating) -> NavFormerLoss (eq. 10), a batch of
512 D_ssl pairs -> BYOLLoss (eq. 8), one backward of L = L_BYOL + L_DT (eq. 11), AdamW + Adam steps, BYOL's EMA
update. Overrides go on the command line (hydra), e.g.::

    python recipes/navformer/navformer.py data.exploration_path=/data/e data.collision_path=/data/ca \\
        data.ssl_path=/data/ssl ablation=no_thsc model.autocast_dtype=bfloat16

A mistake the user can fix is printed as one line, ``navformer.py: error: <message>``, with exit status 2, like
``navformer train`` (``NAVFORMER_DEBUG=1`` shows the traceback); a refused run leaves no hydra folder behind.
"""

from __future__ import annotations

import hydra
from torchrl._utils import timeit
from utils import log_metrics, make_progress_bar, make_train_config, make_trainer

from navformer_rl.recipe_errors import user_errors


@hydra.main(config_path="", config_name="config", version_base="1.3")
def main(cfg) -> None:
    # A mistake (unknown ablation, missing dataset, batch larger than a dataset, ...) ends in one line and
    # exit status 2 (NAVFORMER_DEBUG=1: the traceback)
    with user_errors("navformer.py"):
        # Configuration -> datasets, model, losses, optimisers, logger (resumes when cfg.resume and a
        # checkpoint exists)
        train_cfg = make_train_config(cfg)
        trainer = make_trainer(train_cfg)
        iterations = train_cfg.optim.iterations

        timeit.erase()
        pbar = make_progress_bar(train_cfg, trainer.iteration)
        while trainer.iteration < iterations:
            # sample (D_e | D_ca) + D_ssl -> L_DT + L_BYOL -> backward -> AdamW / Adam -> EMA
            metrics = trainer.step()
            log_metrics(trainer, metrics)
            if trainer.validation_due():  # eval-mode L_DT on held-out D_e / D_ca (validation.* paths)
                with timeit("validation"):
                    trainer.log(trainer.validate(), timings=False)
            if trainer.iteration % train_cfg.checkpoint.interval == 0 or trainer.iteration == iterations:
                with timeit("checkpoint"):
                    trainer.save_checkpoint()
            pbar.update(1)
            pbar.set_postfix(loss=f"{metrics['loss']:.4f}", fps=f"{metrics['frames_per_s']:.0f}")
        pbar.close()
        trainer.close()  # the thread that draws batches ahead (data.prefetch)
        print(f"run directory: {trainer.run_dir}")


if __name__ == "__main__":
    main()
