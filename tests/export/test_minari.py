"""``export_minari``: D_e / D_ca as Minari datasets (round trip, metadata, chunked writing, atomic
publish, errors)."""

from __future__ import annotations

import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import navformer_rl.export.minari as export_module
from navformer_rl.data import open_dataset
from navformer_rl.envs.registration import ENV_ID, register_envs
from navformer_rl.export.minari import (
    MinariNotInstalledError,
    episode_chunks,
    export_minari,
    minari_spaces,
    parse_minari_id,
)

minari = pytest.importorskip("minari")  # the optional extra navformer_rl[minari]
h5py = pytest.importorskip("h5py")


def test_spaces_are_those_of_target_nav():
    register_envs()
    env = gym.make(ENV_ID)
    observation, action = minari_spaces()
    assert observation == env.observation_space and action == env.action_space
    env.close()


def test_episode_chunks_known_answers():
    assert episode_chunks([3, 4, 5, 9], 8) == [(0, 2), (2, 3), (3, 4)]
    assert episode_chunks([3, 4, 5, 9], 1) == [(0, 1), (1, 2), (2, 3), (3, 4)]
    assert episode_chunks([3, 4, 5, 9], 21) == [(0, 4)]
    assert episode_chunks([], 5) == []
    with pytest.raises(ValueError, match="chunk_steps must be an integer >= 1, got 0"):
        episode_chunks([1], 0)


@pytest.mark.parametrize(
    ("text", "parsed"),
    [("navformer/e-v0", ("navformer", "e", 0)), ("nav/sub/e-small-v12", ("nav/sub", "e-small", 12))],
)
def test_ids_parse_like_minari(text, parsed):
    assert parse_minari_id(text) == parsed
    assert minari.dataset.minari_dataset.parse_dataset_id(text) == parsed


@pytest.mark.parametrize(
    "text", ["e-v0", "navformer/e", "navformer/e-vx", "a/e-v0", "navformer/e v0-v1", "/e-v0"]
)
def test_ids_without_namespace_or_version_are_refused(text):
    with pytest.raises(ValueError, match=f"Minari dataset id {text!r} is not NAMESPACE/NAME-vN"):
        parse_minari_id(text)


@pytest.mark.parametrize("kind", ["e", "ca"])
def test_every_episode_equals_its_source_trajectory(source_datasets, minari_path, kind):
    folder = export_minari(source_datasets[kind], f"navformer/{kind}-v0")
    assert folder == minari_path / "navformer" / f"{kind}-v0"
    assert sorted(p.name for p in folder.iterdir()) == ["data"]  # no temp folder, no lock left
    source = open_dataset(source_datasets[kind])
    dataset = minari.load_dataset(f"navformer/{kind}-v0")
    assert (dataset.total_episodes, dataset.total_steps) == (source.num_trajectories, len(source))
    seen = 0
    for episode in dataset.iterate_episodes():
        start, steps = int(source.episodes.start[episode.id]), int(source.episodes.length[episode.id])
        rows = source.rows[start : start + steps]
        pixels = episode.observations["pixels"]
        assert pixels.dtype == np.uint8 and pixels.shape == (steps + 1, 84, 84, 3)
        np.testing.assert_array_equal(pixels[:steps], rows["pixels"].numpy())
        np.testing.assert_array_equal(pixels[steps], pixels[steps - 1])  # the final observation repeats
        target = source.targets[int(source.episodes.target_id[episode.id])].numpy()
        np.testing.assert_array_equal(episode.observations["target_pixels"], np.stack([target] * (steps + 1)))
        assert episode.actions.dtype == np.float32
        np.testing.assert_array_equal(episode.actions, rows["action"].numpy())
        np.testing.assert_array_equal(episode.rewards, rows["next", "reward"][:, 0].numpy())
        np.testing.assert_array_equal(episode.terminations, rows["next", "terminated"][:, 0].numpy())
        np.testing.assert_array_equal(episode.truncations, rows["next", "truncated"][:, 0].numpy())
        collision = rows["next", "collision"][:, 0].numpy()
        np.testing.assert_array_equal(episode.infos["collision"], np.concatenate([[False], collision]))
        assert episode.terminations[-1] and episode.rewards[-1] == 1.0  # synthetic trajectories succeed
        seen += 1
    assert seen == source.num_trajectories


def test_metadata_records_provenance_spaces_and_env_spec(source_datasets, minari_path):
    export_minari(source_datasets["e"], "navformer/e-v0", author="tester")
    export_minari(source_datasets["ca"], "navformer/ca-v0")
    assert {"navformer/e-v0", "navformer/ca-v0"} <= set(minari.list_local_datasets())
    assert (minari_path / "navformer" / "namespace_metadata.json").is_file()
    e, ca = minari.load_dataset("navformer/e-v0"), minari.load_dataset("navformer/ca-v0")
    register_envs()
    assert e.env_spec.to_json() == gym.spec(ENV_ID).to_json()
    assert ca.env_spec is None
    for dataset in (e, ca):
        assert (dataset.observation_space, dataset.action_space) == minari_spaces()
    env = e.recover_environment()
    assert env.observation_space == e.observation_space
    env.close()
    for dataset, kind in ((e, "e"), (ca, "ca")):
        meta = dataset.storage.metadata
        source = open_dataset(source_datasets[kind]).metadata
        ours = meta["navformer_rl"]
        for key in ("kind", "settings", "seeds", "counts", "statistics", "package_version", "schema_version"):
            assert ours[key] == source[key], key
        assert "content_hashes" not in ours
        assert ours["source"]["folder"] == str(source_datasets[kind].resolve())
        assert meta["algorithm_name"] == "synthetic (navformer_rl.data.synthetic)"
        assert meta["jpeg_encoding"] is False and meta["dataset_size"] > 0
        assert f"{source['counts']['items']} " in meta["description"]
    assert e.storage.metadata["author"] == {"tester"} and ca.storage.metadata["author"] == {"navformer_rl"}
    assert e.storage.metadata["requirements"] == ["navformer_rl"]
    assert "no environment spec is recorded" in ca.storage.metadata["description"]


def _hdf5_content(path: Path) -> dict[str, object]:
    """Every group's attributes and every dataset's dtype, shape and bytes in an HDF5 file."""
    content: dict[str, object] = {}

    def visit(name: str, item) -> None:
        attrs = {key: np.asarray(value).tolist() for key, value in item.attrs.items()}
        if isinstance(item, h5py.Dataset):
            content[name] = (item.dtype.str, item.shape, item[()].tobytes(), attrs)
        else:
            content[name] = attrs

    with h5py.File(path, "r") as file:
        file.visititems(visit)
    return content


def test_chunked_writing_equals_unchunked_and_bounds_each_chunk(source_datasets, tmp_path, monkeypatch):
    from minari.dataset._storages.hdf5_storage import HDF5Storage

    written: list[int] = []
    original = HDF5Storage.update_episodes

    def spy(self, episodes):
        episodes = list(episodes)
        written.append(sum(len(e.rewards) for e in episodes))
        return original(self, episodes)

    monkeypatch.setattr(HDF5Storage, "update_episodes", spy)
    lengths = open_dataset(source_datasets["e"]).episodes.length.tolist()
    small = export_minari(source_datasets["e"], "navformer/e-v0", tmp_path / "small", chunk_steps=8)
    assert len(written) == len(episode_chunks(lengths, 8)) > 1
    assert max(written) <= max(8, max(lengths)) and sum(written) == sum(lengths)
    whole = export_minari(source_datasets["e"], "navformer/e-v0", tmp_path / "whole", chunk_steps=10**6)
    assert written[-1] == sum(lengths)
    assert _hdf5_content(small / "data" / "main_data.hdf5") == _hdf5_content(
        whole / "data" / "main_data.hdf5"
    )
    meta_small = minari.dataset.minari_storage.MinariStorage.read_raw_metadata(small / "data")
    meta_whole = minari.dataset.minari_storage.MinariStorage.read_raw_metadata(whole / "data")
    meta_small.pop("dataset_size"), meta_whole.pop("dataset_size")
    assert meta_small == meta_whole


def test_an_existing_id_is_kept_unless_force(source_datasets, minari_path):
    folder = export_minari(source_datasets["e"], "navformer/x-v0")
    with pytest.raises(FileExistsError, match=r"navformer/x-v0 already exists in .*--force"):
        export_minari(source_datasets["ca"], "navformer/x-v0")
    assert minari.load_dataset("navformer/x-v0").total_episodes == 5
    export_minari(source_datasets["ca"], "navformer/x-v0", force=True)
    assert minari.load_dataset("navformer/x-v0").total_episodes == 6
    assert sorted(p.name for p in folder.iterdir()) == ["data"]


def test_a_failed_export_leaves_the_previous_dataset_and_nothing_else(
    source_datasets, minari_path, monkeypatch
):
    folder = export_minari(source_datasets["e"], "navformer/x-v0")

    def crash(*args, **kwargs):
        raise RuntimeError("simulated crash while writing")

    monkeypatch.setattr(export_module, "_episode_buffers", crash)
    with pytest.raises(RuntimeError, match="simulated crash"):
        export_minari(source_datasets["ca"], "navformer/x-v0", force=True)
    assert minari.load_dataset("navformer/x-v0").total_episodes == 5
    assert sorted(p.name for p in folder.iterdir()) == ["data"]
    with pytest.raises(RuntimeError, match="simulated crash"):
        export_minari(source_datasets["ca"], "navformer/y-v0")
    assert not (minari_path / "navformer" / "y-v0").exists()
    with pytest.raises(RuntimeError, match="simulated crash"):
        export_minari(source_datasets["ca"], "other/deeper/y-v0")
    assert sorted(p.name for p in minari_path.iterdir()) == ["navformer"]


def test_without_minari_the_error_says_how_to_install(source_datasets, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "minari", None)
    with pytest.raises(MinariNotInstalledError, match=r'pip install "navformer_rl\[minari\]"') as info:
        export_minari(source_datasets["e"], "navformer/e-v0", tmp_path / "minari")
    assert "\n" not in str(info.value)
    assert not (tmp_path / "minari").exists()
