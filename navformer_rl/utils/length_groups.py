"""Groups of right-padded trajectories of similar length:
what ``split_by_length`` and ``LengthGroups`` crop."""

from __future__ import annotations

import torch


def length_sorted_groups(mask: torch.Tensor, groups: int) -> list[tuple[torch.Tensor, int]]:
    """``[(rows, steps)]``: the trajectories of a right-padded bool ``mask`` ``[N, T]`` ordered by valid
    length (stable: ties keep the batch's order) and cut into ``min(groups, N)`` consecutive groups of
    near-equal size (the first ``N % groups`` one larger). ``rows``: int64 indices into the batch; ``steps``:
    the group's longest valid length (at least 1), so cropping the group to ``[:, :steps]`` drops only
    padding.
    """
    if groups < 1:
        raise ValueError(f"groups must be >= 1, got {groups}")
    lengths = mask.sum(dim=1)
    order = torch.sort(lengths, stable=True).indices
    split = torch.tensor_split(order, min(groups, mask.shape[0]))
    longest = lengths.cpu()  # one host copy for every group's length
    return [(rows, max(int(longest[rows.cpu()].max()), 1)) for rows in split]
