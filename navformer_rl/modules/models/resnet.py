"""ResNet-18 image encoder in plain torch (Table IV ablation "NavFormer with ResNet18").

No torchvision and no downloads: the weights are randomly initialised (Kaiming), unlike the paper's
ImageNet-pretrained ResNet18 (see ``docs/model.md``, "Deviations from the paper").
"""

from __future__ import annotations

from torch import Tensor, nn

from navformer_rl.modules.models.cnn import ImageEncoder


class BasicBlock(nn.Module):
    """Two 3x3 conv-BN layers with an identity (or 1x1 conv-BN) shortcut: ``[M, c_in, H, W] -> [M, c_out, H/s, W/s]``."""

    def __init__(self, c_in: int, c_out: int, stride: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1, bias=False)
        self.bn1 = nn.BatchNorm2d(c_out)
        self.conv2 = nn.Conv2d(c_out, c_out, 3, stride=1, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(c_out)
        self.relu = nn.ReLU(inplace=True)
        self.shortcut: nn.Module = nn.Identity()
        if stride != 1 or c_in != c_out:
            self.shortcut = nn.Sequential(
                nn.Conv2d(c_in, c_out, 1, stride=stride, bias=False), nn.BatchNorm2d(c_out)
            )

    def forward(self, x: Tensor) -> Tensor:
        y = self.relu(self.bn1(self.conv1(x)))
        y = self.bn2(self.conv2(y))
        return self.relu(y + self.shortcut(x))


class ResNet18Encoder(ImageEncoder):
    """ResNet-18 (He et al. 2016): stem conv7/2 + maxpool, 4 stages x 2 BasicBlocks (64-128-256-512),
    global average pool, then Linear 512 -> ``d_out``.  84 px: 42 -> 21 -> 21 -> 11 -> 6 -> 3 -> pool.
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
            nn.BatchNorm2d(64),
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
