import numpy as np
import torch

from navformer_rl.data import open_dataset
from navformer_rl.data.card import sample_sheet, save_png


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
    statics = ds.rows["pixels_static"]
    assert any(torch.equal(torch.from_numpy(sheet[:, :84].copy()), s) for s in statics)
