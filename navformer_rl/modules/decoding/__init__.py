"""Inference only: KV-cached decoding of a ``NavFormerModel``'s parts, one timestep per call.

``IncrementalNavFormer`` (the decoder state) runs the model's own parameters through fused helpers:
``FusedConvEncoders`` (f_s and f_g as one convolution stack), ``StepLayers`` (token embeddings and the
head as precomputed tables), ``TransformerStep`` (the GPT-2 blocks as plain tensor ops) or the compiled
kernel of ``native``. Depends on ``navformer_rl.modules.models``, never the reverse.
"""

from navformer_rl.modules.decoding.fused_encoders import FusedConvEncoders
from navformer_rl.modules.decoding.incremental import IncrementalNavFormer, use_native_kernel

__all__ = ["FusedConvEncoders", "IncrementalNavFormer", "use_native_kernel"]
