"""The encoders' mean ablation of the probe (navformer_rl.evaluation.diagnose.knockout): the mean over the
valid steps, known answers of the loss's rise and its interval, and the table."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from navformer_rl.evaluation.diagnose.knockout import (
    knockout_key,
    knockout_markdown,
    knockout_sets,
    knockout_summary,
    mean_embedding,
)


def test_mean_embedding_averages_only_the_valid_steps_and_keeps_the_dtype():
    embedding = torch.tensor(
        [[[1.0, 2.0], [3.0, 4.0], [100.0, 100.0]], [[5.0, 6.0], [7.0, 8.0], [9.0, 10.0]]]
    )
    mask = torch.tensor([[True, True, False], [True, True, True]])
    mean = mean_embedding(embedding.bfloat16(), mask)
    assert mean.shape == embedding.shape and mean.dtype == torch.bfloat16
    expected = torch.tensor([25.0, 30.0]) / 5  # the padded step (100, 100) is left out
    torch.testing.assert_close(mean.float(), expected.expand(2, 3, 2), rtol=1e-2, atol=0)


def _frames(without: np.ndarray) -> dict[str, np.ndarray]:
    expert = np.zeros((6, 2))
    own = np.full((6, 2), 0.1)  # squared error 0.02 per frame
    return {
        "action": expert,
        "action_own": own,
        "trajectory": np.array([4, 4, 4, 9, 9, 9]),
        knockout_key("static"): own.copy(),
        knockout_key("general"): without,
    }


def test_knockout_summary_known_answers():
    without = np.array([[0.1, 0.1]] * 3 + [[0.1, 0.5]] * 3)  # trajectory 9: squared error 0.26
    summary = knockout_summary(_frames(without), resamples=200, seed=0)
    assert summary["loss"] == pytest.approx(0.02)
    static, general = summary["encoders"]["static"], summary["encoders"]["general"]
    assert static["change"] == [0.0, 0.0]  # the same action without it: the policy takes nothing from it
    assert static["increase"] == static["low"] == static["high"] == 0.0
    assert general["change"] == pytest.approx([0.0, 0.2])
    assert general["loss"] == pytest.approx(0.14)
    assert general["increase"] == pytest.approx(0.12)
    # two trajectories resampled whole: each draw's rise is 0 (both the first), 0.12 or 0.24 (both the second)
    assert general["low"] == pytest.approx(0.0) and general["high"] == pytest.approx(0.24)
    assert knockout_summary({"action": np.zeros((1, 2)), "trajectory": np.zeros(1)}) == {}


def test_knockout_markdown_has_a_row_per_model_and_encoder():
    summary = knockout_summary(_frames(np.full((6, 2), 0.3)), resamples=50)
    text = knockout_markdown({"NavFormer": summary})
    rows = [
        "| NavFormer | general | 0.200, 0.200 | 0.0200 -> 0.1800 | +0.1600 [+0.1600, +0.1600] | +800% |",
        "| NavFormer | static | 0.000, 0.000 | 0.0200 -> 0.0200 | +0.0000 [+0.0000, +0.0000] | +0% |",
    ]
    assert all(row in text for row in rows)


def test_knockout_sets_add_all_encoders_only_to_a_model_with_several():
    assert knockout_sets(("static", "general")) == {
        "static": ("static",),
        "general": ("general",),
        "all": ("static", "general"),
    }
    assert knockout_sets(("general",)) == {"general": ("general",)}
