"""The paper's model on tensors (§IV): config, image encoders, the DVE, the causal transformer, the heads.

Training kernels (CPU attention with dropout, dropout, the conv weight gradient) sit in ``ops``; the
inference-only decoding code in ``navformer_rl.modules.decoding``.
"""

from navformer_rl.modules.models.cnn import ConvEncoder, ImageEncoder, images_to_float
from navformer_rl.modules.models.config import MODEL_ABLATIONS, NavFormerConfig
from navformer_rl.modules.models.dve import ENCODER_NAMES, DualVisualEncoder, make_encoder
from navformer_rl.modules.models.gpt import GPT2Blocks, KVCache
from navformer_rl.modules.models.navformer import NavFormerModel, upgrade_state_dict
from navformer_rl.modules.models.resnet import ResNet18Encoder
from navformer_rl.modules.models.thsc import ActionHead, ObservationHead, THSCHead, make_head
from navformer_rl.modules.models.transformer import (
    HIDDEN_NAMES,
    MODALITIES,
    CausalTransformer,
    TokenEmbedding,
    sliding_window_mask,
)

__all__ = [
    "ENCODER_NAMES",
    "HIDDEN_NAMES",
    "MODALITIES",
    "MODEL_ABLATIONS",
    "ActionHead",
    "CausalTransformer",
    "ConvEncoder",
    "DualVisualEncoder",
    "GPT2Blocks",
    "ImageEncoder",
    "KVCache",
    "NavFormerConfig",
    "NavFormerModel",
    "ObservationHead",
    "ResNet18Encoder",
    "THSCHead",
    "TokenEmbedding",
    "images_to_float",
    "make_encoder",
    "make_head",
    "sliding_window_mask",
    "upgrade_state_dict",
]
