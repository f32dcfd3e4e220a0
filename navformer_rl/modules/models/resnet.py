"""ResNet-18 image encoder in plain torch (Table IV ablation "NavFormer with ResNet18").

No torchvision and no downloads: the weights are randomly initialised (Kaiming), unlike the paper's
ImageNet-pretrained ResNet18 (see ``docs/model.md``, "Deviations from the paper").

Normalisation is GroupNorm (32 groups, Wu & He 2018), not torchvision's BatchNorm: in training the encoder
sees three differently distributed inputs in separate calls (BYOL's augmented views, the target images, the
observation frames), each of which BatchNorm would normalise by its own batch statistics while its running
statistics blend all three, so evaluation would compute another function than training (measured on the
ablation: DT loss 0.07 in train mode vs 0.58 in eval mode on the same batches, ``docs/model.md`` deviation
12), and the train-mode statistics of a trajectory's frames let later frames reach earlier predictions.
GroupNorm normalises each image on its own: train and eval modes compute the same function, and
micro-batches / trajectory chunks leave the outputs unchanged. Same affine parameters as BatchNorm, no
buffers.
"""

from __future__ import annotations

from torch import Tensor, nn

from navformer_rl.modules.models.cnn import ImageEncoder

GROUPS = 32
"""GroupNorm groups of every normalisation layer (Wu & He 2018's default; 64-512 channels divide by it)."""


def norm(channels: int) -> nn.GroupNorm:
    """The encoder's normalisation layer: affine GroupNorm with ``GROUPS`` groups (weight 1, bias 0)."""
    return nn.GroupNorm(GROUPS, channels)


class BasicBlock(nn.Module):
    """Two 3x3 conv-GN layers with an identity (or 1x1 conv-GN) shortcut:
    ``[M, c_in, H, W] -> [M, c_out, H/s, W/s]``."""

    def __init__(self, c_in: int, c_out: int, stride: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1, bias=False)
        self.norm1 = norm(c_out)
        self.conv2 = nn.Conv2d(c_out, c_out, 3, stride=1, padding=1, bias=False)
        self.norm2 = norm(c_out)
        self.relu = nn.ReLU(inplace=True)
        self.shortcut: nn.Module = nn.Identity()
        if stride != 1 or c_in != c_out:
            self.shortcut = nn.Sequential(nn.Conv2d(c_in, c_out, 1, stride=stride, bias=False), norm(c_out))

    def forward(self, x: Tensor) -> Tensor:
        y = self.relu(self.norm1(self.conv1(x)))
        y = self.norm2(self.conv2(y))
        return self.relu(y + self.shortcut(x))


class ResNet18Encoder(ImageEncoder):
    """ResNet-18 (He et al. 2016) with GroupNorm: stem conv7/2 + maxpool, 4 stages x 2 BasicBlocks
    (64-128-256-512), global average pool, then Linear 512 -> ``d_out``.  84 px: 42 -> 21 -> 21 -> 11 -> 6
    -> 3 -> pool.  Each image is normalised on its own, so the output does not depend on the mode
    (``train`` / ``eval``) nor on the other images of the batch.
    """

    def __init__(
        self,
        d_out: int = 128,
        image_size: int = 84,
        micro_batch: int | None = None,
        channels_last: bool = True,
    ) -> None:
        super().__init__(image_size, d_out, micro_batch, channels_last)
        self.stem = nn.Sequential(
            nn.Conv2d(3, 64, 7, stride=2, padding=3, bias=False),
            norm(64),
            nn.ReLU(inplace=True),
            nn.MaxPool2d(3, stride=2, padding=1),
        )
        stages, c_in = [], 64
        for c_out, stride in ((64, 1), (128, 2), (256, 2), (512, 2)):
            stages += [BasicBlock(c_in, c_out, stride), BasicBlock(c_out, c_out, 1)]
            c_in = c_out
        self.stages = nn.Sequential(*stages)
        self.pool = nn.AdaptiveAvgPool2d(1)
        self.linear = nn.Linear(512, d_out)
        for module in self.modules():
            if isinstance(module, nn.Conv2d):
                nn.init.kaiming_normal_(module.weight, mode="fan_out", nonlinearity="relu")

    def encode_nchw(self, x: Tensor) -> Tensor:
        """x: float ``[M, 3, H, W]`` -> ``[M, d_out]``."""
        return self.linear(self.pool(self.stages(self.stem(x))).flatten(1))
