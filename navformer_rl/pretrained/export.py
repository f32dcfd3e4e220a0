"""Export a trained checkpoint as shipped weights: its run part, a model card and the registry entry."""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from navformer_rl.pretrained.card import check_prose, evaluation_facts, render_card, training_facts
from navformer_rl.training.pretrained_registry import (
    CARD_FILENAME,
    PRETRAINED_PREFIX,
    check_name,
    file_sha256,
    pretrained_root,
    read_registry,
    write_registry_entry,
)
from navformer_rl.utils.durable import publish_folder


def write_pretrained(
    checkpoint: str | os.PathLike,
    name: str,
    *,
    evaluations: Sequence[str | os.PathLike] = (),
    card: Mapping[str, Any] | str | os.PathLike | None = None,
    out_dir: str | os.PathLike | None = None,
    overwrite: bool = False,
) -> Path:
    """Ship ``checkpoint`` as ``pretrained:NAME``: write ``out_dir/NAME/`` and its registry entry.

    The checkpoint's run part (``config.json``, ``model.safetensors``: float32, byte for byte) is copied,
    the model card ``MODEL_CARD.md`` written from the measured facts (:mod:`navformer_rl.pretrained.card`),
    and ``out_dir/registry.json`` given NAME's method and the files' sha256. The folder appears atomically
    (written aside, then renamed into place).

    Args:
        checkpoint: any path :func:`~navformer_rl.training.checkpoint.resolve_checkpoint` accepts (a run
            directory: its latest checkpoint).
        name: the shipped name (``navformer``, ``dt``, ...;
            :data:`~navformer_rl.training.pretrained_registry.NAME_PATTERN`).
        evaluations: ``navformer evaluate`` output folders of exactly these weights (their ``run.json``
            sha256 is checked); their SR / SPL / CR tables with intervals go on the card.
        card: the card's prose (:data:`~navformer_rl.pretrained.card.PROSE_FIELDS`), as a mapping or the path
            of a JSON file.
        out_dir: the pretrained root to write into (default: :func:`pretrained_root`, the package's
            ``navformer_rl/pretrained/weights`` unless ``NAVFORMER_PRETRAINED_DIR`` is set).
        overwrite: replace weights already shipped under NAME (FileExistsError otherwise).

    Returns:
        The folder ``out_dir/NAME``.
    """
    from navformer_rl.baselines.dt import is_dt_config
    from navformer_rl.training.checkpoint import (
        CONFIG_FILENAME,
        WEIGHTS_FILENAME,
        load_policy_model,
        read_checkpoint_config,
        resolve_checkpoint,
    )

    check_name(name)
    root = pretrained_root() if out_dir is None else Path(out_dir)
    root.mkdir(parents=True, exist_ok=True)
    final = root / name
    if not overwrite and (name in read_registry(root) or final.exists()):
        raise FileExistsError(
            f"{final} (pretrained:{name}) already exists; pass overwrite (--force) to replace it"
        )
    prose = check_prose(_read_card(card))
    source = resolve_checkpoint(checkpoint)
    config, model = load_policy_model(source)  # refuses a foreign, corrupt or mismatched checkpoint
    header = read_checkpoint_config(source)
    method = "dt" if is_dt_config(config) else "navformer"
    weights_sha256 = file_sha256(source / WEIGHTS_FILENAME)
    evaluated = [evaluation_facts(Path(folder), weights_sha256) for folder in evaluations]
    state = model.state_dict()

    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.", suffix=".tmp", dir=root))
    try:
        for filename in (CONFIG_FILENAME, WEIGHTS_FILENAME):
            shutil.copyfile(source / filename, tmp / filename)
        files = {
            filename: {"bytes": (tmp / filename).stat().st_size, "sha256": file_sha256(tmp / filename)}
            for filename in (CONFIG_FILENAME, WEIGHTS_FILENAME)
        }
        text = render_card(
            PRETRAINED_PREFIX + name,
            method,
            files,
            parameters=sum(tensor.numel() for tensor in state.values()),
            dtypes=sorted({str(tensor.dtype).removeprefix("torch.") for tensor in state.values()}),
            training=training_facts(source, header),
            evaluations=evaluated,
            prose=prose,
        )
        (tmp / CARD_FILENAME).write_text(text, encoding="utf-8")
        publish_folder(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    entry = {"method": method, "files": {filename: info["sha256"] for filename, info in files.items()}}
    write_registry_entry(root, name, entry)
    return final


def _read_card(card: Mapping[str, Any] | str | os.PathLike | None) -> Any:
    """The card's prose fields: ``card`` itself, the JSON object in the file it names, or none."""
    if card is None:
        return {}
    if isinstance(card, Mapping):
        return card
    path = Path(card)
    if not path.is_file():
        raise FileNotFoundError(f"card file {str(path)!r} does not exist")
    try:
        return json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"card file {path} is not valid JSON ({error})") from None
