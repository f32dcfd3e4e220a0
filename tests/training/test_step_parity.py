"""The refactored training step trains as the code before it: 4 tiny iterations of several configurations
give the losses and weights recorded with the trainer of commit e821897 (before ``train_step`` and the
``make_*`` factories), on the same tiny datasets and seeds.

Bit-identical on the CPU they were recorded on (``RECORDED_ON``: torch's CPU capability); elsewhere the
kernels may round differently, and the values are compared to 1e-4.
"""

from __future__ import annotations

import pytest
import torch

from navformer_rl.training import build_trainer

RECORDED_ON = "AVX512"
"""``torch.backends.cpu.get_cpu_capability()`` of the machine that recorded :data:`RECORDED`."""

RECORDED = {
    "default": (
        [],
        [9.114943265914917, 8.776565730571747, 8.580210208892822, 7.4778813123703],
        (79.08116726208272, 4046.0772692441215),
    ),
    "frozen": (
        ["encoder_training=frozen"],
        [9.114943265914917, 8.74848484992981, 8.320961236953735, 7.645792603492737],
        (79.78949323460078, 4039.1065449769403),
    ),
    "adamw": (
        ["optim.encoder_optimizer=adamw"],
        [9.114943265914917, 8.682601928710938, 8.47457480430603, 7.542121648788452],
        (77.91371867142553, 4107.849329886934),
    ),
    "chunks2": (
        ["optim.trajectory_chunks=2"],
        [9.230698943138123, 8.601416170597076, 8.501797914505005, 7.509485363960266],
        (79.33447606644083, 4046.36468339132),
    ),
    "lengthgroups": (
        ["optim.length_groups=2"],
        [9.230698823928833, 8.540292382240295, 8.723007559776306, 7.5715450048446655],
        (78.19149267648217, 4046.004543730317),
    ),
    "bins": (
        ["model.action_bins=5"],
        [11.203781127929688, 9.695880651473999, 9.833650827407837, 9.620351791381836],
        (84.45517265217615, 4071.223212196672),
    ),
    "no_ssl": (
        ["ablation=no_ssl"],
        [0.9326693415641785, 0.6895884275436401, 1.8299493789672852, 1.1589648723602295],
        (78.9809441206416, 3960.0162983574046),
    ),
    "weight": (
        ["ssl.loss_weight=0.5"],
        [4.956832647323608, 4.841963827610016, 5.162981271743774, 4.196410655975342],
        (79.74002570274381, 4045.680656460444),
    ),
    "clip": (
        ["optim.clip_grad_norm=0.05"],
        [9.114943265914917, 8.773432493209839, 8.493597745895386, 7.36601459980011],
        (81.08542124639261, 3981.0956145754517),
    ),
}
"""name: (overrides, ``loss`` of iterations 1-4, (sum, sum of absolute values) of the weights after 4)."""


@pytest.mark.parametrize("name", sorted(RECORDED))
def test_four_iterations_give_the_recorded_losses_and_weights(tiny_config, name):
    overrides, losses, (weights_sum, weights_abs_sum) = RECORDED[name]
    trainer = build_trainer(tiny_config(*overrides, "device=cpu", "optim.iterations=4"))
    try:
        got = [trainer.step()["loss"] for _ in range(4)]
    finally:
        trainer.close()
    state = trainer.model.state_dict()
    weights = [state[key].detach().double() for key in sorted(state)]
    summed = (sum(float(w.sum()) for w in weights), sum(float(w.abs().sum()) for w in weights))
    if torch.backends.cpu.get_cpu_capability() == RECORDED_ON:
        assert got == losses
        assert summed == (weights_sum, weights_abs_sum)
    else:
        assert got == pytest.approx(losses, rel=1e-4)
        assert summed == pytest.approx((weights_sum, weights_abs_sum), rel=1e-4)
