"""NavFormer as TensorDict modules: the paper's parts on tensors (``models``), their TensorDict modules and
composition (``actors``), KV-cached decoding (``decoding``) and the closed-loop policy (``inference``)."""

from __future__ import annotations

from navformer_rl.utils.lazy import lazy_exports

_EXPORTS = {
    "ActionHead": "navformer_rl.modules.models",
    "ACTION_LOGITS_KEY": "navformer_rl.modules.actors",
    "BinnedActionHead": "navformer_rl.modules.models",
    "CausalTransformer": "navformer_rl.modules.models",
    "ConvEncoder": "navformer_rl.modules.models",
    "DualVisualEncoder": "navformer_rl.modules.models",
    "IncrementalNavFormer": "navformer_rl.modules.decoding",
    "MODEL_ABLATIONS": "navformer_rl.modules.models",
    "NAVFORMER_IN_KEYS": "navformer_rl.modules.actors",
    "NAVFORMER_OUT_KEYS": "navformer_rl.modules.actors",
    "NavFormerConfig": "navformer_rl.modules.models",
    "NavFormerModel": "navformer_rl.modules.models",
    "NavFormerPolicy": "navformer_rl.modules.inference",
    "SINGLE_ROBOT_POLICY_KEYS": "navformer_rl.modules.inference",
    "ObservationHead": "navformer_rl.modules.models",
    "ResNet18Encoder": "navformer_rl.modules.models",
    "THSCHead": "navformer_rl.modules.models",
    "dve_module": "navformer_rl.modules.actors",
    "head_module": "navformer_rl.modules.actors",
    "make_navformer_actor": "navformer_rl.modules.actors",
    "MissingKeyError": "navformer_rl.modules.inputs",
    "NavFormerActor": "navformer_rl.modules.actors",
    "LengthGroups": "navformer_rl.modules.actors",
    "transformer_module": "navformer_rl.modules.actors",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
