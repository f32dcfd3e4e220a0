"""NavFormer as TensorDict modules: the paper's parts on tensors (``models``), their TensorDict modules and
composition (``actors``), KV-cached decoding (``decoding``) and the closed-loop policy (``inference``)."""

from navformer_rl.modules.actors import (
    NAVFORMER_IN_KEYS,
    NAVFORMER_OUT_KEYS,
    dve_module,
    head_module,
    make_navformer_actor,
    transformer_module,
)
from navformer_rl.modules.decoding import IncrementalNavFormer
from navformer_rl.modules.inference import NavFormerPolicy
from navformer_rl.modules.models import (
    MODEL_ABLATIONS,
    ActionHead,
    CausalTransformer,
    ConvEncoder,
    DualVisualEncoder,
    NavFormerConfig,
    NavFormerModel,
    ObservationHead,
    ResNet18Encoder,
    THSCHead,
)

__all__ = [
    "MODEL_ABLATIONS",
    "NAVFORMER_IN_KEYS",
    "NAVFORMER_OUT_KEYS",
    "ActionHead",
    "CausalTransformer",
    "ConvEncoder",
    "DualVisualEncoder",
    "IncrementalNavFormer",
    "NavFormerConfig",
    "NavFormerModel",
    "NavFormerPolicy",
    "ObservationHead",
    "ResNet18Encoder",
    "THSCHead",
    "dve_module",
    "head_module",
    "make_navformer_actor",
    "transformer_module",
]
