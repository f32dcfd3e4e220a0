import numpy as np
import torch

from navformer_rl.data import open_dataset
from navformer_rl.data.card import sample_sheet, save_png
from navformer_rl.data.dataset import NavDataset


def test_trajectory_sheet_layout_and_content(e_dataset, tmp_path):
    ds = open_dataset(e_dataset)
    sheet = sample_sheet(ds, n=2, frames=3)
    assert sheet.shape == (2 * 84 + 4, 4 * 84 + 3 * 4, 3) and sheet.dtype == np.uint8
    # row 0: target image of trajectory 0, then its first step
    assert np.array_equal(sheet[:84, :84], ds.targets[0].numpy())
    assert np.array_equal(sheet[:84, 88:172], ds.rows["pixels"][0].numpy())
    import cv2

    path = save_png(sheet, tmp_path / "img" / "e.png")
    assert np.array_equal(cv2.imread(str(path))[:, :, ::-1], sheet)


def test_ssl_sheet_shows_pairs(ssl_dataset):
    ds = open_dataset(ssl_dataset)
    sheet = sample_sheet(ds, n=1, frames=2)
    assert sheet.shape == (84, 2 * 84 + 4, 3)
    statics, dynamics = ds.rows["pixels_static"], ds.rows["pixels_dynamic"]
    # the sheet shows pairs where the robots are visible first: the first pair whose two images differ
    differs = [not torch.equal(a, b) for a, b in zip(statics, dynamics, strict=True)]
    i = differs.index(True)
    assert i == 0  # every synthetic pair shows a robot: the sheet's pair is the dataset's first
    assert np.array_equal(sheet[:, :84], statics[i].numpy())
    assert np.array_equal(sheet[:, -84:], dynamics[i].numpy())  # o^d beside its o^s
    # the same first pairs without a visible robot (o^d = o^s): the sheet skips them for pair 2
    rows = ds.rows[:6].to_tensordict()
    rows["pixels_dynamic"][:2] = rows["pixels_static"][:2]
    assert not torch.equal(dynamics[0], statics[0])  # a copy: the shared dataset's files are untouched
    sheet = sample_sheet(NavDataset(ds.root, ds.metadata, rows, None), n=1, frames=2)
    assert np.array_equal(sheet[:, :84], statics[2].numpy())
    assert np.array_equal(sheet[:, -84:], dynamics[2].numpy())
