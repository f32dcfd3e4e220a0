"""DerivedCache: tables computed from parameters are rebuilt exactly when a source changes."""

import torch

from navformer_rl.modules.decoding.derived import DerivedCache


def test_rebuilds_only_after_an_in_place_update_or_a_replaced_tensor():
    weight = torch.nn.Parameter(torch.ones(2, 3))
    builds = []

    def build() -> torch.Tensor:
        builds.append(1)
        return weight.detach().t().contiguous()

    cache = DerivedCache([weight])
    first = cache.get(build)
    assert cache.get(build) is first and len(builds) == 1  # nothing changed: the same table
    with torch.no_grad():
        weight.mul_(2.0)  # in place: _version moves
    torch.testing.assert_close(cache.get(build), torch.full((3, 2), 2.0))
    assert len(builds) == 2
    weight.data = torch.zeros(2, 3)  # a replaced tensor: data_ptr moves
    torch.testing.assert_close(cache.get(build), torch.zeros(3, 2))
    assert len(builds) == 3 and cache.get(build) is cache.get(build)


def test_owners_are_freed_without_the_garbage_collector():
    """The caches keep no bound method of their owner, so a dropped decoder frees its tables at once."""
    import gc
    import weakref

    from navformer_rl.modules import IncrementalNavFormer, NavFormerConfig, NavFormerModel

    model = NavFormerModel(NavFormerConfig(d_embed=32, d_head=16, n_blocks=1)).eval()
    decoder = IncrementalNavFormer(model, 1)
    frame = torch.zeros(1, 84, 84, 3, dtype=torch.uint8)
    decoder.step(frame, frame, torch.ones(1, 1), torch.zeros(1, 2))
    parts = [weakref.ref(part) for part in (decoder._transformer, decoder._layers, decoder._fused_encoders)]
    gc.disable()
    try:
        del decoder
        assert all(part() is None for part in parts)
    finally:
        gc.enable()
