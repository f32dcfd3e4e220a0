"""Deep Siamese Actor-Critic (DSAC; Zhu et al., ICRA 2017) as adapted in paper §VII.A.

Zhu et al. embed the observation and the target image with the same (Siamese) network, fuse the two
embeddings, and put scene-specific layers and the policy / value heads on top. §VII.A keeps a single set
of scene-generic layers for every training world (so the policy can run in unseen worlds), and here the
actions are continuous: a tanh-squashed Gaussian over (linear, angular) velocity
(:mod:`~navformer_rl.baselines.actor_critic`)::

    e_o = f(o_t), e_g = f(o_g)                  f: the paper's 3-conv CNN (ConvEncoder), shared weights
    h   = ReLU(W_f [e_o ; e_g])                 fusion layer
    z   = ReLU(W_s h)                           scene-generic layer  -> ("agents", "features")
    a_t ~ tanh(N(W_a z, sigma)), V = w_v z      heads (actor_critic)

Zhu et al.'s frozen ImageNet ResNet-50 and four stacked history frames are replaced by the paper's
trainable CNN on the current frame (``docs/baselines.md``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch
from tensordict.nn import TensorDictModule
from torch import Tensor, nn

from navformer_rl.baselines.actor_critic import (
    FEATURES_KEY,
    PIXELS_KEY,
    TARGET_PIXELS_KEY,
    ActorCriticNet,
)
from navformer_rl.constants import IMAGE_SIZE
from navformer_rl.modules.models.cnn import ConvEncoder
from navformer_rl.utils.checks import check_int, check_number


@dataclass(frozen=True)
class DSACConfig:
    """DSAC's sizes.

    Attributes:
        d_embed: width of the Siamese embedding of each image.
        hidden: width of the fusion and scene-generic layers (Zhu et al.: 512).
        init_std: initial pre-tanh action standard deviation.
        image_size: side of the square uint8 images.
    """

    d_embed: int = 512
    hidden: int = 512
    init_std: float = 1.0
    image_size: int = IMAGE_SIZE

    def __post_init__(self) -> None:
        check_int(self.d_embed, "model.d_embed")
        check_int(self.hidden, "model.hidden")
        check_number(self.init_std, "model.init_std", greater_than=0.0)
        check_int(self.image_size, "model.image_size", minimum=36)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


class DSACTrunk(nn.Module):
    """Siamese CNN + fusion + scene-generic layer.

    ``forward(pixels, target_pixels)``: uint8 ``[*, H, W, 3]`` each -> features float ``[*, hidden]``.
    """

    def __init__(self, config: DSACConfig) -> None:
        super().__init__()
        self.encoder = ConvEncoder(config.d_embed, config.image_size)
        self.fusion = nn.Sequential(nn.Linear(2 * config.d_embed, config.hidden), nn.ReLU())
        self.scene = nn.Sequential(nn.Linear(config.hidden, config.hidden), nn.ReLU())

    def forward(self, pixels: Tensor, target_pixels: Tensor) -> Tensor:
        embedded = self.encoder(torch.stack([pixels, target_pixels.expand_as(pixels)], dim=-4))
        return self.scene(self.fusion(embedded.flatten(-2)))


def make_dsac(config: DSACConfig | None = None) -> ActorCriticNet:
    """A fresh DSAC network; its trunk reads ``("agents", "pixels")``, ``("agents", "target_pixels")``."""
    config = config or DSACConfig()
    trunk = TensorDictModule(
        DSACTrunk(config), in_keys=[PIXELS_KEY, TARGET_PIXELS_KEY], out_keys=[FEATURES_KEY]
    )
    return ActorCriticNet(trunk, config.hidden, config.init_std)
