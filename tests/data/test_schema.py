import numpy as np
import pytest
import torch

from navformer_rl.data.schema import (
    SCHEMA_VERSION,
    TRAJECTORY_FIELDS,
    DatasetKind,
    check_rows,
    return_to_go,
    trajectory_rows,
)


def _trajectory(T=4, succeeded=True, **overrides):
    reward = np.zeros(T, np.float32)
    if succeeded:
        reward[-1] = 1.0
    kwargs = dict(
        pixels=np.arange(T * 84 * 84 * 3, dtype=np.int64).reshape(T, 84, 84, 3).astype(np.uint8),
        action=np.linspace(-1, 1, 2 * T, dtype=np.float32).reshape(T, 2),
        reward=reward,
        collision=np.array([False, True, False, False][:T]),
        pose=np.arange(3 * T, dtype=np.float32).reshape(T, 3),
        target_position=np.array([1.5, 2.5]),
        succeeded=succeeded,
        task=1,
        episode=7,
        target_id=3,
    )
    kwargs.update(overrides)
    return trajectory_rows(**kwargs)


def test_return_to_go_eq3_hand_computed():
    # R_t = sum_{t'>=t} r_t'  (reward of step t included)
    assert return_to_go(np.array([0, 0, 0, 1.0])).tolist() == [1, 1, 1, 1]
    assert return_to_go(np.array([0.5, 0, 2.0, 1.0])).tolist() == [3.5, 3.0, 3.0, 1.0]
    assert return_to_go(np.zeros(3)).tolist() == [0, 0, 0]


def test_trajectory_rows_match_schema_and_values():
    td = _trajectory()
    check_rows(td, TRAJECTORY_FIELDS, "test")
    assert td.batch_size == torch.Size([4])
    assert td["step"].tolist() == [0, 1, 2, 3]
    assert td["episode"].tolist() == [7] * 4 and td["target_id"].tolist() == [3] * 4
    assert td["task"].tolist() == [1] * 4
    assert td["return_to_go"][:, 0].tolist() == [1, 1, 1, 1]
    assert td["next", "reward"][:, 0].tolist() == [0, 0, 0, 1]
    assert td["next", "done"][:, 0].tolist() == [False, False, False, True]
    assert td["next", "terminated"][:, 0].tolist() == [False, False, False, True]
    assert not td["next", "truncated"].any()
    assert td["next", "collision"][:, 0].tolist() == [False, True, False, False]
    assert td["privileged", "target_position"].tolist() == [[1.5, 2.5]] * 4
    assert td["pixels"].dtype == torch.uint8 and td["pixels"].shape == (4, 84, 84, 3)


def test_failed_trajectory_is_truncated_not_terminated():
    td = _trajectory(succeeded=False)
    assert td["next", "truncated"][:, 0].tolist() == [False, False, False, True]
    assert not td["next", "terminated"].any()
    assert td["return_to_go"].sum() == 0


@pytest.mark.parametrize(
    "override, message",
    [
        ({"pixels": np.zeros((4, 84, 84, 3), np.float32)}, "uint8"),
        ({"pixels": np.zeros((4, 3, 84, 84), np.uint8)}, "shape"),
        ({"action": np.full((4, 2), 1.5, np.float32)}, r"\[-1, 1\]"),
        ({"action": np.full((4, 2), np.nan, np.float32)}, "NaN"),
        ({"pose": np.zeros((3, 3))}, "pose"),
    ],
)
def test_trajectory_rows_refuse_bad_input(override, message):
    with pytest.raises(ValueError, match=message):
        _trajectory(**override)


def test_check_rows_names_the_bad_key():
    td = _trajectory()
    td["action"] = td["action"].double()
    with pytest.raises(ValueError, match="'action'.*float64"):
        check_rows(td, TRAJECTORY_FIELDS, "here")
    del td["pixels"]
    with pytest.raises(ValueError, match="missing key 'pixels'"):
        check_rows(td, TRAJECTORY_FIELDS, "here")


def test_kind_parsing():
    assert DatasetKind.parse("ca") is DatasetKind.COLLISION_AVOIDANCE
    assert SCHEMA_VERSION == 1
    with pytest.raises(ValueError, match="unknown dataset kind 'x'"):
        DatasetKind.parse("x")
