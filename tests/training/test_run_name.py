"""``logger.exp_name``: named after the ablation unless given; a resumed folder keeps its recorded name."""

import json

import pytest

from navformer_rl.training.config import TrainConfig, default_exp_name, named_run


@pytest.mark.parametrize(
    ("ablation", "name"), [("none", "navformer"), ("dt", "dt"), ("no_ssl", "navformer-no_ssl")]
)
def test_a_new_run_is_named_after_its_ablation(tmp_path, ablation, name):
    cfg = TrainConfig(ablation=ablation, output_dir=str(tmp_path))
    assert cfg.logger.exp_name is None
    assert default_exp_name(ablation) == name
    assert named_run(cfg, resuming=False).logger.exp_name == name
    assert cfg.logger.exp_name is None  # the given config is left as it was


def test_a_given_name_is_kept(tmp_path):
    cfg = TrainConfig(ablation="dt", output_dir=str(tmp_path))
    cfg.logger.exp_name = "mine"
    assert named_run(cfg, resuming=True).logger.exp_name == "mine"


def test_a_resumed_folder_keeps_the_name_it_recorded(tmp_path):
    recorded = TrainConfig(ablation="dt", output_dir=str(tmp_path)).to_dict()
    recorded["logger"]["exp_name"] = "navformer"
    (tmp_path / "train_config.json").write_text(json.dumps(recorded))
    cfg = TrainConfig(ablation="dt", output_dir=str(tmp_path))
    assert named_run(cfg, resuming=True).logger.exp_name == "navformer"
    assert named_run(cfg, resuming=False).logger.exp_name == "dt"
