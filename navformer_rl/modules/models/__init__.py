"""The paper's model on tensors (§IV): config, image encoders, the DVE, the causal transformer, the heads.

Training kernels (CPU attention with dropout, dropout, the conv weight gradient) sit in ``ops``; the
inference-only decoding code in ``navformer_rl.modules.decoding``.
"""

from __future__ import annotations

from navformer_rl.utils.lazy import lazy_exports

_EXPORTS = {
    "ActionHead": "navformer_rl.modules.models.heads",
    "BinnedActionHead": "navformer_rl.modules.models.heads",
    "CausalTransformer": "navformer_rl.modules.models.transformer",
    "ConvEncoder": "navformer_rl.modules.models.cnn",
    "DualVisualEncoder": "navformer_rl.modules.models.dve",
    "ENCODER_NAMES": "navformer_rl.modules.models.dve",
    "GPT2Blocks": "navformer_rl.modules.models.gpt",
    "HIDDEN_NAMES": "navformer_rl.modules.models.transformer",
    "ImageEncoder": "navformer_rl.modules.models.cnn",
    "KVCache": "navformer_rl.modules.models.gpt",
    "MODALITIES": "navformer_rl.modules.models.transformer",
    "MODEL_ABLATIONS": "navformer_rl.modules.models.config",
    "NavFormerConfig": "navformer_rl.modules.models.config",
    "NavFormerModel": "navformer_rl.modules.models.navformer",
    "ObservationHead": "navformer_rl.modules.models.heads",
    "ResNet18Encoder": "navformer_rl.modules.models.resnet",
    "THSCHead": "navformer_rl.modules.models.heads",
    "TokenEmbedding": "navformer_rl.modules.models.transformer",
    "images_to_float": "navformer_rl.modules.models.cnn",
    "init_embedding_tables": "navformer_rl.modules.models.transformer",
    "make_encoder": "navformer_rl.modules.models.dve",
    "make_head": "navformer_rl.modules.models.heads",
    "sliding_window_mask": "navformer_rl.modules.models.transformer",
}

__all__ = sorted(_EXPORTS)

__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
