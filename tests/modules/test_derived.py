"""DerivedCache: tables computed from parameters are rebuilt exactly when a source changes."""

import torch

from navformer_rl.modules.models.derived import DerivedCache


def test_rebuilds_only_after_an_in_place_update_or_a_replaced_tensor():
    weight = torch.nn.Parameter(torch.ones(2, 3))
    builds = []

    def build() -> torch.Tensor:
        builds.append(1)
        return weight.detach().t().contiguous()

    cache = DerivedCache([weight], build)
    first = cache.get()
    assert cache.get() is first and len(builds) == 1  # nothing changed: the same table
    with torch.no_grad():
        weight.mul_(2.0)  # in place: _version moves
    torch.testing.assert_close(cache.get(), torch.full((3, 2), 2.0))
    assert len(builds) == 2
    weight.data = torch.zeros(2, 3)  # a replaced tensor: data_ptr moves
    torch.testing.assert_close(cache.get(), torch.zeros(3, 2))
    assert len(builds) == 3 and cache.get() is cache.get()
