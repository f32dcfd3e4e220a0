"""TorchRL's loss contract as one shared check, in the spirit of TorchRL's ``LossModuleTestBase``
(``test/test_cost.py``): a loss module of this package subclasses :class:`LossContract`, says how to make
its loss, a batch and its equation, and inherits every check:

- the input tensordict is left as it was (a steady tensordict);
- ``state_dict`` round-trips (a second loss of other weights computes the same after loading);
- ``set_keys`` renames every input end to end, refuses unknown names, and ``None`` restores a default;
- ``select_out_keys`` / ``reset_out_keys``;
- ``reset_parameters_recursive`` redraws the parameters in place and leaves a working loss;
- the ``loss_*`` entries (what a TorchRL trainer sums) are the paper's equation, and only they carry
  gradients.
"""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.utils import NestedKey
from torch import nn


def trajectories(n: int, steps: int, seed: int = 0) -> TensorDict:
    """TensorDict ``[n]`` of random uint8 images, RTG, actions in [-1, 1], steps 0..T-1 and an all-valid mask
    (per-step keys ``[n, T, ...]``, ``target_pixels`` ``[n, 84, 84, 3]``): the data package's batches."""
    gen = torch.Generator().manual_seed(seed)
    data = {
        "target_pixels": torch.randint(0, 256, (n, 84, 84, 3), dtype=torch.uint8, generator=gen),
        "pixels": torch.randint(0, 256, (n, steps, 84, 84, 3), dtype=torch.uint8, generator=gen),
        "return_to_go": torch.rand(n, steps, 1, generator=gen),
        "action": torch.rand(n, steps, 2, generator=gen) * 2 - 1,
        "step": torch.arange(steps).expand(n, steps).clone(),
        "mask": torch.ones(n, steps, dtype=torch.bool),
    }
    return TensorDict(data, batch_size=[n])


def padded_trajectories() -> TensorDict:
    """Two trajectories of 3 steps, the second padded after its first step."""
    td = trajectories(2, 3, seed=1)
    td["mask"][1, 1:] = False
    return td


class LossContract:
    """The checks; a subclass defines :meth:`make`, :meth:`batch`, :meth:`equation`, :meth:`renamed`,
    :attr:`out_keys` and :attr:`default_keys`."""

    out_keys: tuple[str, ...]
    """The loss's ``out_keys``, in order; those starting with ``loss`` are what a trainer sums."""
    default_keys: dict[str, NestedKey]
    """``tensor_keys`` name -> its default key."""

    def make(self, seed: int = 0) -> tuple[nn.Module, nn.Module]:
        """``(model, loss)``: a fresh model of ``seed``'s weights (deterministic forward) and its loss."""
        raise NotImplementedError

    def batch(self) -> TensorDict:
        """The loss's input."""
        raise NotImplementedError

    def equation(self, model: nn.Module, loss: nn.Module, td: TensorDict) -> torch.Tensor:
        """The sum of the ``loss_*`` entries, computed from the paper's equation (not by the loss)."""
        raise NotImplementedError

    def trained(self, model: nn.Module) -> nn.Module:
        """The part of ``model`` the loss trains (its layers are redrawn by
        ``reset_parameters_recursive``)."""
        return model

    def renamed(self, model: nn.Module, td: TensorDict) -> tuple[nn.Module, TensorDict, torch.Tensor]:
        """``(loss with set_keys renaming every input, td with the inputs under the new names and values
        the default names do not hold, the expected sum of its loss entries)``."""
        raise NotImplementedError

    # -- the checks ---------------------------------------------------------------------------------------
    def loss_entries(self) -> list[str]:
        return [key for key in self.out_keys if key.startswith("loss")]

    def test_input_tensordict_is_left_unchanged(self):
        _, loss = self.make()
        td = self.batch()
        before = td.clone()
        loss(td)
        assert set(td.keys(True, True)) == set(before.keys(True, True))
        assert (td == before).all()

    def test_state_dict_round_trip(self):
        _, loss = self.make(seed=0)
        _, other = self.make(seed=1)
        entry = self.loss_entries()[0]
        assert not torch.equal(other(self.batch())[entry], loss(self.batch())[entry])
        state = loss.state_dict()
        other.load_state_dict(state)
        for key, value in other.state_dict().items():
            torch.testing.assert_close(value, state[key], rtol=0, atol=0)
        expected, got = loss(self.batch()), other(self.batch())
        for key in self.out_keys:
            torch.testing.assert_close(got[key], expected[key], rtol=0, atol=0)

    def test_set_keys_renames_every_input_end_to_end(self):
        model, loss = self.make()
        assert {name: getattr(loss.tensor_keys, name) for name in self.default_keys} == self.default_keys
        renamed, td, expected = self.renamed(model, self.batch())
        new_keys = {getattr(renamed.tensor_keys, name) for name in self.default_keys}
        assert new_keys.isdisjoint(self.default_keys.values())  # every key was renamed
        total = sum(renamed(td)[key] for key in self.loss_entries())
        torch.testing.assert_close(total, expected, rtol=1e-6, atol=1e-7)

    def test_set_keys_refuses_unknown_names_and_none_restores_the_default(self):
        model, loss = self.make()
        name, default = next(iter(self.default_keys.items()))
        loss.set_keys(**{name: "elsewhere"})
        assert getattr(loss.tensor_keys, name) == "elsewhere"
        loss.set_keys(**{name: None})
        assert getattr(loss.tensor_keys, name) == default
        with pytest.raises(ValueError, match="not an accepted tensordict key"):
            loss.set_keys(no_such_key="x")

    def test_select_and_reset_out_keys(self):
        _, loss = self.make()
        assert loss.out_keys == list(self.out_keys)
        first = self.loss_entries()[0]
        loss.select_out_keys(first)
        assert loss.out_keys == [first] and list(loss(self.batch()).keys()) == [first]
        loss.reset_out_keys()
        assert loss.out_keys == list(self.out_keys)
        assert set(loss(self.batch()).keys()) == set(self.out_keys)
        with pytest.raises(ValueError, match="non existent key"):
            loss.select_out_keys("loss_of_nothing")

    def test_reset_parameters_recursive_redraws_in_place(self):
        model, loss = self.make()
        parameters = list(model.parameters())
        trained = self.trained(model).modules()
        layers = [m for m in trained if isinstance(m, (nn.Linear, nn.Conv2d, nn.Embedding))]
        before = [layer.weight.detach().clone() for layer in layers]
        loss.reset_parameters_recursive()
        assert all(a is b for a, b in zip(model.parameters(), parameters, strict=True))  # redrawn in place
        assert layers and all(
            not torch.equal(layer.weight, w) for layer, w in zip(layers, before, strict=True)
        )
        out = loss(self.batch())
        assert all(torch.isfinite(out[key]) for key in self.loss_entries())

    def test_the_loss_entries_sum_to_the_equation(self):
        model, loss = self.make()
        td = self.batch()
        out = loss(td)
        assert [key for key in out.keys() if key.startswith("loss")] == self.loss_entries()
        total = sum(out[key] for key in self.loss_entries())
        torch.testing.assert_close(total, self.equation(model, loss, td), rtol=1e-5, atol=1e-6)

    def test_only_the_loss_entries_carry_gradients(self):
        _, loss = self.make()
        out = loss(self.batch())
        assert all(out[key].requires_grad for key in self.loss_entries())
        assert not any(out[key].requires_grad for key in self.out_keys if not key.startswith("loss"))
        sum(out[key] for key in self.loss_entries()).backward()
        assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in loss.parameters())
