"""Plain ``nn.Module`` models on tensors: encoders, the causal transformer and ``NavFormerModel``."""

from navformer_rl.modules.models.cnn import ConvEncoder, ImageEncoder, images_to_float
from navformer_rl.modules.models.config import MODEL_ABLATIONS, NavFormerConfig
from navformer_rl.modules.models.fused_encoders import FusedConvEncoders
from navformer_rl.modules.models.incremental import IncrementalNavFormer
from navformer_rl.modules.models.navformer import (
    MODALITIES,
    NavFormerModel,
    make_encoder,
    sliding_window_mask,
)
from navformer_rl.modules.models.resnet import ResNet18Encoder
from navformer_rl.modules.models.transformer import CausalTransformer, KVCache

__all__ = [
    "MODALITIES",
    "MODEL_ABLATIONS",
    "CausalTransformer",
    "ConvEncoder",
    "FusedConvEncoders",
    "ImageEncoder",
    "IncrementalNavFormer",
    "KVCache",
    "NavFormerConfig",
    "NavFormerModel",
    "ResNet18Encoder",
    "images_to_float",
    "make_encoder",
    "sliding_window_mask",
]
