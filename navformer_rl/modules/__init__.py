"""NavFormer modules: plain tensor models (``models``), TensorDict wrappers and the inference policy."""

from navformer_rl.modules.actors import NAVFORMER_IN_KEYS, NAVFORMER_OUT_KEYS, make_navformer_actor
from navformer_rl.modules.inference import NavFormerPolicy
from navformer_rl.modules.models import (
    MODEL_ABLATIONS,
    ConvEncoder,
    IncrementalNavFormer,
    NavFormerConfig,
    NavFormerModel,
    ResNet18Encoder,
)

__all__ = [
    "MODEL_ABLATIONS",
    "NAVFORMER_IN_KEYS",
    "NAVFORMER_OUT_KEYS",
    "ConvEncoder",
    "IncrementalNavFormer",
    "NavFormerConfig",
    "NavFormerModel",
    "NavFormerPolicy",
    "ResNet18Encoder",
    "make_navformer_actor",
]
