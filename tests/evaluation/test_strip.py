"""``navformer evaluate strip``: evenly spaced frames of a video side by side, checked on a video whose frames
have known colours."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from navformer_rl.cli import main
from navformer_rl.evaluation import strip
from navformer_rl.evaluation.strip import GAP, frame_label, frame_strip, strip_frame_indices
from navformer_rl.utils.mp4 import Mp4Writer


@pytest.fixture(scope="module")
def grey_ramp(tmp_path_factory):
    """An 11-frame 10 fps video (64 x 48) whose frame i is uniformly grey at 20 * i + 20."""
    path = tmp_path_factory.mktemp("strip") / "ramp.mp4"
    with Mp4Writer(path, fps=10.0, threads=1) as writer:
        for i in range(11):
            writer.write(np.full((48, 64, 3), 20 * i + 20, np.uint8))
    return path


def test_frame_indices_are_even_and_keep_the_first_and_last():
    assert strip_frame_indices(11, 3) == [0, 5, 10]
    assert strip_frame_indices(11, 5) == [0, 2, 5, 8, 10]
    assert strip_frame_indices(3, 5) == [0, 1, 2]
    assert strip_frame_indices(7, 1) == [6]


def test_the_strip_holds_the_chosen_frames_in_order(grey_ramp, tmp_path):
    out = frame_strip(grey_ramp, tmp_path / "strip.png", frames=3, width=3 * 128 + 2 * GAP)
    image = cv2.cvtColor(cv2.imread(str(out)), cv2.COLOR_BGR2RGB)
    assert image.shape == (96, 3 * 128 + 2 * GAP, 3)  # tiles scaled from 64 x 48 to 128 x 96
    for tile, frame in enumerate((0, 5, 10)):  # the top-left of each tile, away from the time label
        x = tile * (128 + GAP) + 64
        assert abs(int(image[20, x, 0]) - (20 * frame + 20)) <= 4
    assert (image[:, 128 : 128 + GAP] == 255).all()  # the white gap


def test_a_frame_is_labelled_with_its_step_and_trial_time():
    """Frame i of an evaluation video is control step i, at 0.2 s per step (CONTROL_DT)."""
    assert frame_label(0) == "step 0, t = 0.0 s"
    assert frame_label(167) == "step 167, t = 33.4 s"
    assert frame_label(500) == "step 500, t = 100.0 s"


def test_the_labels_follow_the_steps_not_the_playback_rate(grey_ramp, tmp_path, monkeypatch):
    """The ramp plays at 10 fps, so its frame 10 is at 1 s of playback; it is step 10, 2 s into the trial."""
    labels = []
    monkeypatch.setattr(strip, "frame_label", lambda index: labels.append(frame_label(index)) or labels[-1])
    frame_strip(grey_ramp, tmp_path / "strip.png", frames=3, width=3 * 128 + 2 * GAP)
    assert labels == ["step 0, t = 0.0 s", "step 5, t = 1.0 s", "step 10, t = 2.0 s"]


def test_bad_input_is_one_line(grey_ramp, tmp_path, capsys):
    with pytest.raises(ValueError, match="expected a .png path"):
        frame_strip(grey_ramp, tmp_path / "strip.jpg")
    with pytest.raises(ValueError, match="frames=0: expected a positive integer"):
        frame_strip(grey_ramp, tmp_path / "s.png", frames=0)
    assert main(["evaluate", "strip", str(tmp_path / "absent.mp4"), "--out", str(tmp_path / "s.png")]) == 2
    assert "no video at" in capsys.readouterr().err
    assert (
        main(["evaluate", "strip", str(grey_ramp), "--out", str(tmp_path / "ok.png"), "--frames", "2"]) == 0
    )
    assert (tmp_path / "ok.png").is_file()
