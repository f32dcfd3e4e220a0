"""Memory-Augmented Target-Driven Navigation (MA-TDN; Mezghani et al., IROS 2022) as adapted in paper §VII.A.

Each robot keeps a memory of the embeddings of its past observations; an attention module queried by the
current observation and the target retrieves from it (continuous actions: a tanh-squashed Gaussian,
:mod:`~navformer_rl.baselines.actor_critic`)::

    e_t = f(o_t), g = f(o_g)                            f: the paper's 3-conv CNN, shared weights
    K = V = [m_1 .. m_M, e_t] + slot embedding          m: the last M embeddings e_{t-M} .. e_{t-1}
    r_t = MultiHeadAttention(W_q [e_t ; g], K, V)       empty slots masked out
    z   = MLP([r_t ; e_t ; g])                          -> ("agents", "features")

The memory is recurrent state carried in the tensordict, TorchRL-style: the trunk reads
``("agents", "memory")`` float ``[A, M, d]`` and ``("agents", "memory_mask")`` bool ``[A, M]`` (True = slot
filled; slot M is the newest) and writes the memory of the next step to ``("next", "agents", "memory")`` /
``("next", "agents", "memory_mask")``, which ``step_mdp`` moves to the root; :func:`memory_primer` adds them
to an env's specs (zeros = empty on reset). The memory is emptied wherever ``("agents", "step_count")`` is 0
(the first step of an episode), and a missing memory counts as empty, so the policy also runs on a plain
``MultiRobotNavEnv`` (the evaluation harness). Stored embeddings are detached: in a PPO update they are the
memory the policy had when it acted, and gradients reach the encoder through ``e_t`` and ``g``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch
from tensordict.nn import TensorDictModule
from torch import Tensor, nn
from torchrl.data import Categorical, Composite, Unbounded
from torchrl.envs import TensorDictPrimer

from navformer_rl.baselines.actor_critic import (
    AGENTS,
    FEATURES_KEY,
    PIXELS_KEY,
    STEP_COUNT_KEY,
    TARGET_PIXELS_KEY,
    ActorCriticNet,
)
from navformer_rl.constants import IMAGE_SIZE
from navformer_rl.modules.models.cnn import ConvEncoder
from navformer_rl.utils.checks import check_int, check_number

MEMORY_KEY = (AGENTS, "memory")
MEMORY_MASK_KEY = (AGENTS, "memory_mask")


@dataclass(frozen=True)
class MATDNConfig:
    """MA-TDN's sizes.

    Attributes:
        d_embed: width of the image embeddings and of the memory slots.
        memory_size: M, how many past embeddings the memory holds (first in, first out).
        n_heads: attention heads (``d_embed`` must be divisible by it).
        hidden: width of the MLP after the attention.
        init_std: initial pre-tanh action standard deviation.
        image_size: side of the square uint8 images.
    """

    d_embed: int = 128
    memory_size: int = 32
    n_heads: int = 4
    hidden: int = 512
    init_std: float = 1.0
    image_size: int = IMAGE_SIZE

    def __post_init__(self) -> None:
        check_int(self.d_embed, "model.d_embed")
        check_int(self.memory_size, "model.memory_size")
        check_int(self.n_heads, "model.n_heads")
        if self.d_embed % self.n_heads:
            raise ValueError(
                f"model.d_embed={self.d_embed} must be divisible by model.n_heads={self.n_heads}"
            )
        check_int(self.hidden, "model.hidden")
        check_number(self.init_std, "model.init_std", greater_than=0.0)
        check_int(self.image_size, "model.image_size", minimum=36)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


class MATDNTrunk(nn.Module):
    """Siamese CNN, memory attention and MLP (module docstring).

    ``forward(pixels, target_pixels, memory, memory_mask, step_count)``: uint8 ``[*, H, W, 3]`` twice, float
    ``[*, M, d]`` or None, bool ``[*, M]`` or None, int64 ``[*, 1]`` or None -> ``(features [*, hidden],
    next memory [*, M, d], next mask [*, M])``.
    """

    def __init__(self, config: MATDNConfig) -> None:
        super().__init__()
        d, m = config.d_embed, config.memory_size
        self.memory_size = m
        self.encoder = ConvEncoder(d, config.image_size)
        self.slot_embedding = nn.Parameter(torch.zeros(m + 1, d))  # the age of each slot; the last is e_t
        nn.init.normal_(self.slot_embedding, std=0.02)
        self.query = nn.Linear(2 * d, d)
        self.norm_query = nn.LayerNorm(d)
        self.norm_memory = nn.LayerNorm(d)
        self.attention = nn.MultiheadAttention(d, config.n_heads, batch_first=True)
        self.mlp = nn.Sequential(
            nn.Linear(3 * d, config.hidden), nn.ReLU(), nn.Linear(config.hidden, config.hidden), nn.ReLU()
        )

    def forward(
        self,
        pixels: Tensor,
        target_pixels: Tensor,
        memory: Tensor | None = None,
        memory_mask: Tensor | None = None,
        step_count: Tensor | None = None,
    ) -> tuple[Tensor, Tensor, Tensor]:
        lead = pixels.shape[:-3]
        embedded = self.encoder(torch.stack([pixels, target_pixels.expand_as(pixels)], dim=-4))
        current, goal = embedded.unbind(-2)  # [*, d] each
        d, m = current.shape[-1], self.memory_size
        if memory is None or memory_mask is None:
            memory = current.new_zeros(*lead, m, d)
            memory_mask = torch.zeros(*lead, m, dtype=torch.bool, device=current.device)
        if step_count is not None:  # a new episode starts with an empty memory
            fresh = step_count.reshape(*lead, 1) == 0
            memory = memory.masked_fill(fresh[..., None], 0.0)
            memory_mask = memory_mask & ~fresh
        tokens = self.norm_memory(torch.cat([memory, current[..., None, :]], dim=-2) + self.slot_embedding)
        valid = torch.cat([memory_mask, memory_mask.new_ones(*lead, 1)], dim=-1)
        query = self.norm_query(self.query(torch.cat([current, goal], dim=-1)))
        read, _ = self.attention(
            query.reshape(-1, 1, d),
            tokens.reshape(-1, m + 1, d),
            tokens.reshape(-1, m + 1, d),
            key_padding_mask=~valid.reshape(-1, m + 1),
            need_weights=False,
        )
        features = self.mlp(torch.cat([read.reshape(*lead, d), current, goal], dim=-1))
        next_memory = torch.cat([memory[..., 1:, :], current.detach()[..., None, :]], dim=-2)
        next_mask = torch.cat([memory_mask[..., 1:], memory_mask.new_ones(*lead, 1)], dim=-1)
        return features, next_memory, next_mask


def make_matdn(config: MATDNConfig | None = None) -> ActorCriticNet:
    """A fresh MA-TDN network; its trunk reads pixels, target pixels, the memory and the step count and
    writes the features and the next memory (module docstring)."""
    config = config or MATDNConfig()
    trunk = TensorDictModule(
        MATDNTrunk(config),
        in_keys=[PIXELS_KEY, TARGET_PIXELS_KEY, MEMORY_KEY, MEMORY_MASK_KEY, STEP_COUNT_KEY],
        out_keys=[FEATURES_KEY, ("next", *MEMORY_KEY), ("next", *MEMORY_MASK_KEY)],
        strict=False,  # a missing memory is passed as None: an empty memory
    )
    return ActorCriticNet(trunk, config.hidden, config.init_std)


def memory_primer(config: MATDNConfig, n_agents: int) -> TensorDictPrimer:
    """A ``TensorDictPrimer`` registering the memory of ``n_agents`` robots in an env's specs; it sets an
    empty memory (zeros) on every reset."""
    n = check_int(n_agents, "n_agents")
    return TensorDictPrimer(
        Composite(
            {
                AGENTS: Composite(
                    memory=Unbounded((n, config.memory_size, config.d_embed), dtype=torch.float32),
                    memory_mask=Categorical(2, (n, config.memory_size), dtype=torch.bool),
                    shape=(n,),
                )
            }
        ),
        default_value=0.0,
        expand_specs=False,
    )
