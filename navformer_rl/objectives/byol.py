"""``BYOLLoss``: self-supervised training of the dual visual encoders (paper §IV.B, eqs. 6-8)."""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictParams, dispatch
from tensordict.utils import NestedKey
from torch import Tensor, nn
from torchrl.objectives import LossModule, SoftUpdate

from navformer_rl.modules.inputs import require_keys
from navformer_rl.modules.models.cnn import ImageEncoder
from navformer_rl.modules.models.config import AUTOCAST_DTYPES
from navformer_rl.modules.models.dve import DualVisualEncoder
from navformer_rl.objectives.byol_augment import BYOLAugmentation


def byol_mlp(d_in: int, d_hidden: int, d_out: int) -> nn.Sequential:
    """BYOL projector / predictor: Linear(d_in, d_hidden) - BatchNorm1d - ReLU - Linear(d_hidden, d_out)."""
    return nn.Sequential(
        nn.Linear(d_in, d_hidden), nn.BatchNorm1d(d_hidden), nn.ReLU(inplace=True), nn.Linear(d_hidden, d_out)
    )


class EncoderProjector(nn.Module):
    """Online/target branch body of one encoder: float NCHW views ``[B, 3, H, W]`` -> projections
    ``[B, d_proj]``."""

    def __init__(self, encoder: ImageEncoder, projector: nn.Module) -> None:
        super().__init__()
        self.encoder = encoder
        self.projector = projector

    def forward(self, views: Tensor) -> Tensor:
        return self.projector(self.encoder.forward_float(views))


def normalized_mse(prediction: Tensor, projection: Tensor) -> Tensor:
    """Eq. 6 per sample: ``|| p / ||p|| - z / ||z|| ||^2 = 2 - 2 cos(p, z)``; ``[B, d] x [B, d] -> [B]``."""
    return (F.normalize(prediction.float(), dim=-1) - F.normalize(projection.float(), dim=-1)).pow(2).sum(-1)


def byol_tau(step: int, total_steps: int, tau_base: float = 0.996) -> float:
    """BYOL's cosine EMA schedule: ``tau_k = 1 - (1 - tau_base) (cos(pi k / K) + 1) / 2``
    (tau_0 = tau_base, tau_K = 1)."""
    if total_steps <= 0:
        raise ValueError(f"total_steps={total_steps!r}: expected a positive int")
    k = min(max(step, 0), total_steps)
    return 1.0 - (1.0 - tau_base) * (math.cos(math.pi * k / total_steps) + 1.0) / 2.0


class BYOLTauSchedule:
    """Sets ``updater.eps`` (TorchRL's name for BYOL's tau) from ``byol_tau`` at every ``step()``.

    The schedule owns ``updater.eps``: from construction on it is ``byol_tau(step, total_steps, tau_base)``
    (``tau_base`` defaults to the paper's 0.996), whatever ``eps`` the ``SoftUpdate`` was created with.

    Call order per iteration: ``loss.backward(); optimizer.step(); updater.step(); schedule.step()``.
    ``state_dict`` / ``load_state_dict`` carry the step counter for resumption.
    """

    def __init__(self, updater: SoftUpdate, total_steps: int, tau_base: float = 0.996) -> None:
        if not 0.5 <= tau_base <= 1.0:
            raise ValueError(f"tau_base={tau_base!r}: expected a value in [0.5, 1]")
        self.updater, self.total_steps, self.tau_base = updater, total_steps, tau_base
        self.step_count = 0
        self.updater.eps = byol_tau(0, total_steps, tau_base)

    def step(self) -> float:
        """Advance one iteration; returns the tau now in use."""
        self.step_count += 1
        self.updater.eps = byol_tau(self.step_count, self.total_steps, self.tau_base)
        return self.updater.eps

    def state_dict(self) -> dict[str, int]:
        return {"step_count": self.step_count}

    def load_state_dict(self, state: dict[str, int]) -> None:
        self.step_count = int(state["step_count"])
        self.updater.eps = byol_tau(self.step_count, self.total_steps, self.tau_base)


class BYOLLoss(LossModule):
    """BYOL for f_s and/or f_g (eqs. 6-8) with an EMA target network.

    Per encoder ``e`` in {static, general}: online branch = encoder f + projector g + predictor q; target
    branch = EMA copies of f and g (``convert_to_functional(create_target_params=True)``, updated by a
    ``torchrl.objectives.SoftUpdate``; schedule with ``BYOLTauSchedule``). Views:

    - static encoder: ``v = aug(o^s)``, ``v' = aug(o^d)`` (same scene without / with other robots);
    - general encoder: ``v = aug(o^d)`` (the same view), ``v' = aug'(o^d)`` (an independent augmentation).

    ``L_e = mean_batch[ l(q(g(f(v))), sg(g'(f'(v')))) + l(q(g(f(v'))), sg(g'(f'(v)))) ]`` with l of eq. 6,
    and ``loss_byol = sum_e L_e`` (eq. 8).

    The encoders passed in (or those of the ``DualVisualEncoder`` passed in: ``BYOLLoss(model.dve)``) are
    *the same module objects* as the model's ``dve.static_encoder`` / ``dve.general_encoder``: one
    optimizer over ``joint_parameters(dt_loss, byol_loss)`` trains them with
    ``L = L_BYOL + L_DT`` (eq. 11). Target parameters are buffers, absent from ``parameters()``.

    Keys (``set_keys``): ``pixels_static`` uint8 ``[B, 84, 84, 3]`` (o^s), ``pixels_dynamic`` uint8
    ``[B, 84, 84, 3]`` (o^d). Outputs (scalars, ``out_keys``; ``select_out_keys`` / ``reset_out_keys`` work):

    - ``loss_byol``: L_BYOL (eq. 8), the only entry carrying gradients and the only one starting with
      ``loss``, so TorchRL's convention of summing the ``loss*`` entries optimises eq. 8 once;
    - ``byol_<name>`` for each encoder: L_e, detached (its share of ``loss_byol``, for logging);
    - ``projection_std_<name>``, detached: std of the normalised online projections over the batch
      (averaged over dims), a collapse monitor (-> 0 on collapse, about 1/sqrt(d_proj) when healthy).

    ``reset_parameters_recursive()`` re-draws the online encoders, projectors and predictors (the encoders
    are the model's own, as with any TorchRL loss sharing its networks) and restarts the target as a copy
    of the online encoders and projectors.

    Args:
        static_encoder / general_encoder: the encoders (None to skip one; at least one is needed), or a
            ``DualVisualEncoder`` alone as first argument (its f_s and f_g).
        projection_dim / hidden_dim: MLP sizes (defaults 128 / 512, see ``docs/model.md``).
        augmentation: a ``BYOLAugmentation`` (default: a new one seeded with ``seed``).
        autocast_dtype: ``"bfloat16"`` / ``"float16"`` / None - autocast around the encoders and MLPs.

    Training splits the parameters as §VI does: the encoders with the rest of the model (AdamW, also trained
    by L_DT), the projectors and predictors that only this loss has with Adam; after each step
    ``SoftUpdate.step()`` moves the EMA target.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.objectives import SoftUpdate
        >>> from navformer_rl.modules import NavFormerConfig, NavFormerModel
        >>> from navformer_rl.objectives import BYOLLoss, BYOLTauSchedule
        >>> model = NavFormerModel(NavFormerConfig())
        >>> byol = BYOLLoss(model.dve, seed=0)  # the model's own f_s and f_g
        >>> updater = SoftUpdate(byol, eps=0.996)
        >>> schedule = BYOLTauSchedule(updater, total_steps=100)
        >>> model_ids = {id(p) for p in model.parameters()}
        >>> heads = torch.optim.Adam([p for p in byol.parameters() if id(p) not in model_ids], lr=4e-4)
        >>> pairs = TensorDict(
        ...     {
        ...         "pixels_static": torch.randint(0, 256, (4, 84, 84, 3), dtype=torch.uint8),
        ...         "pixels_dynamic": torch.randint(0, 256, (4, 84, 84, 3), dtype=torch.uint8),
        ...     },
        ...     batch_size=[4],
        ... )
        >>> out = byol(pairs)
        >>> sorted(out.keys())
        ['byol_general', 'byol_static', 'loss_byol', 'projection_std_general', 'projection_std_static']
        >>> out["loss_byol"].backward(); heads.step(); updater.step(); tau = schedule.step()
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable input keys.

        Attributes:
            pixels_static: o^s, the view without dynamic obstacles. Defaults to ``"pixels_static"``.
            pixels_dynamic: o^d, the same view with the other robots. Defaults to ``"pixels_dynamic"``.
        """

        pixels_static: NestedKey = "pixels_static"
        pixels_dynamic: NestedKey = "pixels_dynamic"

    tensor_keys: _AcceptedKeys
    default_keys = _AcceptedKeys
    online_network: nn.ModuleDict
    online_network_params: TensorDictParams
    target_online_network_params: TensorDictParams
    predictor: nn.ModuleDict
    predictor_params: TensorDictParams
    target_predictor_params: TensorDictParams

    def __init__(
        self,
        static_encoder: ImageEncoder | DualVisualEncoder | None,
        general_encoder: ImageEncoder | None = None,
        *,
        projection_dim: int = 128,
        hidden_dim: int = 512,
        augmentation: BYOLAugmentation | None = None,
        seed: int = 0,
        autocast_dtype: str | None = None,
    ) -> None:
        super().__init__()
        if isinstance(static_encoder, DualVisualEncoder):
            if general_encoder is not None:
                raise ValueError(
                    "BYOLLoss: pass a DualVisualEncoder alone, or static_encoder / general_encoder"
                )
            static_encoder, general_encoder = static_encoder.static_encoder, static_encoder.general_encoder
        encoders = {
            name: enc
            for name, enc in (("static", static_encoder), ("general", general_encoder))
            if enc is not None
        }
        if not encoders:
            raise ValueError("BYOLLoss: expected at least one of static_encoder / general_encoder")
        if autocast_dtype is not None and autocast_dtype not in AUTOCAST_DTYPES:
            raise ValueError(
                f"autocast_dtype={autocast_dtype!r}: expected None or one of {tuple(AUTOCAST_DTYPES)}"
            )
        self.encoder_names = tuple(encoders)
        online = nn.ModuleDict(
            {
                name: EncoderProjector(enc, byol_mlp(enc.d_out, hidden_dim, projection_dim))
                for name, enc in encoders.items()
            }
        )
        predictor = nn.ModuleDict(
            {name: byol_mlp(projection_dim, hidden_dim, projection_dim) for name in encoders}
        )
        self.convert_to_functional(online, "online_network", create_target_params=True)
        self.convert_to_functional(predictor, "predictor", create_target_params=False)
        self._out_keys = [
            "loss_byol",
            *(f"byol_{name}" for name in self.encoder_names),
            *(f"projection_std_{name}" for name in self.encoder_names),
        ]
        self.augmentation = augmentation if augmentation is not None else BYOLAugmentation(seed=seed)
        self.autocast_dtype = autocast_dtype

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        pass

    def train(self, mode: bool = True) -> BYOLLoss:
        """``nn.Module.train`` that also reaches the projector and predictor networks (their BatchNorm),
        which TorchRL's ``convert_to_functional`` keeps outside the child modules; ``eval()`` calls it."""
        super().train(mode)
        self.online_network.train(mode)
        self.predictor.train(mode)
        return self

    @property
    def in_keys(self) -> list[NestedKey]:
        keys = [self.tensor_keys.pixels_dynamic]
        if "static" in self.encoder_names:
            keys.append(self.tensor_keys.pixels_static)
        return keys

    @property
    def out_keys(self) -> list[str]:
        return self._out_keys

    @out_keys.setter
    def out_keys(self, values: list[str]) -> None:
        self._out_keys = list(values)

    def reset_parameters_recursive(self) -> None:
        """Re-draw the online networks (each layer's ``reset_parameters``, as TorchRL's losses do) and copy
        them into the EMA target, the state BYOL starts from."""
        for name in ("online_network", "predictor"):
            module = getattr(self, name)
            with getattr(self, f"{name}_params").to_module(module, preserve_module_state=False):
                self._reset_parameters(module)
        self.target_online_network_params.data.update_(self.online_network_params.data)

    def check_inputs(self, tensordict: TensorDictBase) -> None:
        """Refuse a batch without the image pairs this loss reads, or with images other than uint8
        ``[B, H, W, 3]``, in one line naming the key (``MissingKeyError`` / ``ValueError``)."""
        meanings = {
            self.tensor_keys.pixels_dynamic: "uint8 [B, 84, 84, 3], o^d: the view with the other robots",
            self.tensor_keys.pixels_static: "uint8 [B, 84, 84, 3], o^s: the same view without them",
        }
        required = {key: meanings[key] for key in self.in_keys}
        require_keys(
            tensordict,
            required,
            "BYOLLoss",
            "rename it with loss.set_keys(pixels_static=..., pixels_dynamic=...)",
        )
        for key in required:
            images = tensordict.get(key)
            if images.dim() != 4 or images.shape[-1] != 3 or images.dtype != torch.uint8:
                raise ValueError(
                    f"BYOLLoss: {key!r} must be uint8 [B, H, W, 3] (one image per pair), got {images.dtype} "
                    f"{list(images.shape)}"
                )

    def make_views(self, tensordict: TensorDictBase) -> dict[str, tuple[Tensor, Tensor]]:
        """The two augmented views (``[B, 3, H, W]``, in the autocast dtype if any) of each encoder.

        One augmentation of o^d serves as the static encoder's v' and the general encoder's v (the two
        losses are separate, so sharing it changes neither; it saves a quarter of the augmentation cost).
        """
        dynamic_view = self._augment(tensordict.get(self.tensor_keys.pixels_dynamic))
        views = {}
        if "static" in self.encoder_names:
            views["static"] = (self._augment(tensordict.get(self.tensor_keys.pixels_static)), dynamic_view)
        if "general" in self.encoder_names:
            views["general"] = (dynamic_view, self._augment(tensordict.get(self.tensor_keys.pixels_dynamic)))
        return views

    def _augment(self, pixels: Tensor) -> Tensor:
        """Augmented views written in the encoders' compute dtype (the autocast dtype) and memory layout."""
        dtype = getattr(torch, self.autocast_dtype) if self.autocast_dtype is not None else torch.float32
        channels_last = all(
            getattr(self.online_network[name].encoder, "channels_last", False) for name in self.encoder_names
        )
        return self.augmentation(pixels, dtype=dtype, channels_last=channels_last)

    @dispatch
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Compute ``loss_byol`` (eq. 8) and the detached per-encoder terms on a batch of image pairs."""
        self.check_inputs(tensordict)
        views = self.make_views(tensordict)
        device_type = next(iter(views.values()))[0].device.type
        autocast = (
            torch.autocast(device_type, dtype=getattr(torch, self.autocast_dtype))
            if self.autocast_dtype is not None
            else contextlib.nullcontext()
        )
        out: dict[str, Tensor] = {}
        total = None
        with autocast:
            for name, (view_a, view_b) in views.items():
                both = torch.cat([view_a, view_b])
                with self.online_network_params.to_module(self.online_network):
                    projection = self.online_network[name](both)
                with self.predictor_params.to_module(self.predictor):
                    prediction = self.predictor[name](projection)
                # preserve_module_state=False (as TorchRL's losses do): the default would turn
                # requires_grad back on for the target parameters, which SoftUpdate then refuses
                target_params = self.target_online_network_params
                with (
                    torch.no_grad(),
                    target_params.to_module(self.online_network, preserve_module_state=False),
                ):
                    target = self.online_network[name](both)
                pred_a, pred_b = prediction.chunk(2)
                target_a, target_b = target.chunk(2)
                loss = (normalized_mse(pred_a, target_b) + normalized_mse(pred_b, target_a)).mean()
                out[f"byol_{name}"] = loss.detach()
                out[f"projection_std_{name}"] = F.normalize(projection.detach().float(), dim=-1).std(0).mean()
                total = loss if total is None else total + loss
        out["loss_byol"] = total
        return TensorDict(out, batch_size=[])


def joint_parameters(*modules: nn.Module) -> list[nn.Parameter]:
    """Trainable parameters of several modules without duplicates (shared encoders appear once).

    ``AdamW(joint_parameters(dt_loss, byol_loss), ...)`` is the single optimizer of eq. 11.
    """
    seen: dict[int, nn.Parameter] = {}
    for module in modules:
        for param in module.parameters():
            if param.requires_grad:
                seen.setdefault(id(param), param)
    return list(seen.values())
