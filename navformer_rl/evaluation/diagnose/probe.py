"""Linear probes of what a checkpoint's visual encoders keep of a camera frame.

NavFormer's and DT's policies see the world only through their encoders' frame embeddings (e^s = f_s(o),
e^ca = f_g(o); DT's single e). Whether an encoder keeps what the navigation network needs is read here with
linear probes (Alain & Bengio, 2016): ridge regressions from one frame's embedding to quantities of that
frame, fitted on half of the held-out trajectories and scored on the other half, so a probe measures what the
embedding carries on mazes neither the probe nor the policy was fitted on. No closed loop and no training of
the policy: the probes read a checkpoint as it is.

The probed quantities, per frame of held-out D_e (one robot and one target per maze):

- ``angular`` / ``linear``: the expert's action at that frame (R²): how much of the expert's command one
  frame's embedding explains linearly (walls ahead, open corridors, the target in view); the navigation
  network adds the history and the target token to it.
- ``in_view``: whether the target lies in the camera's 90° cone within :data:`PROBE_RANGE` metres (walls are
  not checked, as in the teacher-forced edge-of-view measure: some of these targets are hidden), scored as the
  area under the ROC curve of the probe's output (0.5: the embedding does not tell).
- ``bearing``: at the frames with the target in that cone, its bearing (R², and ``bearing_sign``: the share of
  frames whose probe puts the target on the correct side of the image): whether the embedding keeps where in
  the image the target is, the cue a policy needs to turn towards a target at the edge of its view.

Each is probed from every encoder alone (``static``, ``general``, DT's ``general``), from all of a model's
frame embeddings together (``all``), and from what the action head reads at that step (``head``: THSC's
``[h_g; h^ca_o]``, or ``h_o`` without THSC), the navigation network's output teacher-forced on the window so
far: whether what the encoders keep reaches the head; and with THSC from ``h_o`` alone, the part of the head's
input that changes from step to step. Beside the probes,
:mod:`~navformer_rl.evaluation.diagnose.target_reading` reads how the navigation network attends to the target
token and what THSC's target term adds, and :mod:`~navformer_rl.evaluation.diagnose.knockout` how much of the
action rests on each encoder.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from navformer_rl.evaluation.diagnose.actions import HALF_FIELD_OF_VIEW
from navformer_rl.evaluation.diagnose.knockout import (
    KNOCKOUT_PREFIX,
    PAST_ACTIONS,
    knockout_key,
    knockout_markdown,
    knockout_sets,
    knockout_summary,
    mean_embedding,
)
from navformer_rl.evaluation.diagnose.measures import bearing_to
from navformer_rl.evaluation.diagnose.target_reading import (
    READINGS,
    TargetAttentionRecorder,
    TargetSwap,
    head_terms,
    target_reading_markdown,
    target_reading_summary,
)

PROBE_RANGE = 3.0
"""Metres from the robot's centre to the target's within which a target in the camera cone counts as in
view."""

RIDGE = 1e-2
"""Ridge penalty per fitted row on the standardised embeddings (the fit minimises the mean squared error plus
``RIDGE`` times the squared weights)."""

PROBE_JSON, PROBE_MD = "probe.json", "probe.md"

QUANTITIES = ("angular", "linear", "in_view", "bearing", "bearing_sign")

LABELS = ("action", "pose", "target", "trajectory")
"""The per-frame arrays of :func:`frame_embeddings` that are labels, not features."""


def frame_embeddings(
    checkpoint: str | os.PathLike,
    exploration: str | os.PathLike,
    max_trajectories: int | None = None,
    batch_trajs: int = 16,
    seed: int = 0,
    device: str = "cpu",
    context_steps: int | None = None,
    kind: str = "e",
) -> dict[str, np.ndarray]:
    """Every encoder's embedding of every frame of held-out D_e (or D_ca) windows, with the frame's labels.

    The windows are those ``navformer validate`` scores (one per trajectory, at most the model's context,
    drawn with ``seed`` from the first ``max_trajectories`` of a seeded permutation), encoded in eval mode
    under the model's autocast dtype.

    Args:
        checkpoint: any form :func:`~navformer_rl.training.checkpoint.resolve_checkpoint` takes.
        exploration: a D_e folder (held out from the checkpoint's training); a D_ca one with ``kind="ca"``.
        context_steps: the windows' length (default: the model's context, ``window_steps``); at most that.

    Returns:
        ``{"<encoder name>": float32 [N, d] per encoder of the model (``static``, ``general``), "head":
        [N, d'] what the action head reads at that step (``[h_g; h^ca_o]``, d' = 2d, with THSC; ``h_o``
        without), "h_o": [N, d] the observation's hidden state alone (``head`` without THSC), "action":
        [N, 2], "pose": [N, 3], "target": [N, 2], "trajectory": int64 [N], "attention_to_target": [N,
        n_blocks], "attention_keys": int64 [N], "observation_term": [N, 2] and with THSC "target_term":
        [N, 2], "action_own" / "action_swapped": [N, 2] the model's action with the trajectory's target image
        and with another target's, "action_without_<encoder name>": [N, 2] per encoder (and ``_all`` with two
        encoders; ``_past_actions``), the action with that encoder's frame embeddings (the action tokens)
        replaced by their mean}`` over the N valid
        frames (the readings: :mod:`.target_reading` and :mod:`.knockout`; no ``*_term`` with the binned head,
        no ``action_swapped`` when the dataset holds one kind of target). ``head``, ``h_o`` and the actions
        are teacher-forced: the navigation network reads the window's frames, the target image and the
        expert's actions up to that step, as in training.
    """
    import torch

    from navformer_rl.data import open_dataset
    from navformer_rl.data.fit import check_model_reads
    from navformer_rl.training import checkpoint as ckpt
    from navformer_rl.training.validation import FixedTrajectoryBatches, evaluation_mode
    from navformer_rl.utils.devices import check_device, resolve_device

    torch_device = resolve_device(check_device(device))
    if kind not in ("e", "ca"):
        raise ValueError(f"kind={kind!r}: expected 'e' or 'ca'")
    if not os.path.exists(exploration):
        raise FileNotFoundError(f"{kind} dataset {str(exploration)!r} does not exist")
    dataset = open_dataset(exploration, kind=kind)
    config, model = ckpt.load_policy_model(ckpt.resolve_checkpoint(checkpoint))
    check_model_reads(config, {kind: dataset}, {kind: f"{kind} dataset {str(exploration)!r}"}, tunable=False)
    model.to(torch_device)
    dve = model.dve
    knocked_out = knockout_sets(dve.names)  # {"static": ("static",), ..., "all": every encoder}
    knockouts = [knockout_key(name) for name in (*knocked_out, PAST_ACTIONS)]
    rows: dict[str, list[np.ndarray]] = {
        k: [] for k in (*dve.names, "head", "h_o", *LABELS, *READINGS, *knockouts)
    }
    window = config.window_steps if context_steps is None else int(context_steps)
    if not 1 <= window <= config.window_steps:
        raise ValueError(f"context_steps={context_steps!r}: expected 1 to the model's {config.window_steps}")
    batches = FixedTrajectoryBatches(dataset, batch_trajs, window, seed, max_trajectories=max_trajectories)
    swap = TargetSwap(dataset.targets)
    with evaluation_mode(model):
        for batch in batches:
            batch = batch.to(torch_device)
            mask = batch["mask"]
            *observations, e_g = dve(batch["pixels"], batch["target_pixels"], mask)  # [B, T, d] each, [B, d]
            steps = (batch["return_to_go"], batch["action"], batch["step"], mask)
            named = dict(zip(dve.names, observations, strict=True))
            with TargetAttentionRecorder(model.transformer) as attention:
                h_g, h_o, _ = model.transformer(e_g, *steps, **named)
            rows["action_own"].append(_head_actions(model.head, h_g, h_o, mask))
            if swap.available:
                target = batch["target_pixels"]  # [B, H, W, 3], or [B, T, H, W, 3] constant over T
                e_swapped = dve.encode_target(swap.swap(target[:, 0] if target.dim() == 5 else target))
                swapped_g, swapped_o, _ = model.transformer(e_swapped, *steps, **named)
                rows["action_swapped"].append(_head_actions(model.head, swapped_g, swapped_o, mask))
            for name, encoders in knocked_out.items():
                without = {**named, **{e: mean_embedding(named[e], mask) for e in encoders}}
                hidden = model.transformer(e_g, *steps, **without)[:2]
                rows[knockout_key(name)].append(_head_actions(model.head, *hidden, mask))
            past = mean_embedding(batch["action"], mask)
            hidden = model.transformer(e_g, batch["return_to_go"], past, batch["step"], mask, **named)[:2]
            rows[knockout_key(PAST_ACTIONS)].append(_head_actions(model.head, *hidden, mask))
            rows["attention_to_target"].append(attention.weights[mask].cpu().numpy())
            rows["attention_keys"].append(attention.keys.expand_as(mask.cpu())[mask.cpu()].numpy())
            for name, term in head_terms(model.head, h_g, h_o).items():
                rows[name].append(term[mask].cpu().numpy())
            hidden = {"target": h_g, "observation": h_o}
            head = torch.cat([hidden[name] for name in model.head.reads], dim=-1)
            rows["head"].append(head[mask].float().cpu().numpy())
            rows["h_o"].append(h_o[mask].float().cpu().numpy())
            for name, embedding in zip(dve.names, observations, strict=True):
                rows[name].append(embedding[mask].float().cpu().numpy())
            rows["action"].append(batch["action"][mask].float().cpu().numpy())
            rows["pose"].append(batch["privileged", "pose"][mask].float().cpu().numpy())
            rows["target"].append(batch["privileged", "target_position"][mask].float().cpu().numpy())
            trajectory = batch["trajectory"].unsqueeze(1).expand_as(mask)
            rows["trajectory"].append(trajectory[mask].cpu().numpy().astype(np.int64))
    return {key: np.concatenate(parts) for key, parts in rows.items() if parts}


def _head_actions(head: Any, target_hidden: Any, observation_hidden: Any, mask: Any) -> np.ndarray:
    """The action head's float32 ``[N, A]`` actions at the ``N`` valid steps of bool ``mask`` ``[B, T]``,
    from h_g ``[B, d]`` and h_o ``[B, T, d]`` (each head reads what its ``reads`` name)."""
    hidden_of = {"target": target_hidden, "observation": observation_hidden}
    action = head.actions(*(hidden_of[r] for r in head.reads), mask)
    return action[mask].float().cpu().numpy()


def ridge_predict(
    x_fit: np.ndarray, y_fit: np.ndarray, x_test: np.ndarray, ridge: float = RIDGE
) -> np.ndarray:
    """Fit ``y = x w + b`` by ridge regression on standardised ``x`` and predict ``x_test``.

    Args:
        x_fit: float ``[N, d]``; y_fit: float ``[N]`` or ``[N, k]``; x_test: float ``[M, d]``.
        ridge: penalty per fitted row (:data:`RIDGE`).

    Returns:
        float ``[M]`` or ``[M, k]``, the shape of ``y_fit`` beyond its first dimension.
    """
    x_fit, x_test = np.asarray(x_fit, dtype=np.float64), np.asarray(x_test, dtype=np.float64)
    y = np.asarray(y_fit, dtype=np.float64)
    mean, scale = x_fit.mean(axis=0), x_fit.std(axis=0)
    scale[scale == 0] = 1.0
    a, b = (x_fit - mean) / scale, (x_test - mean) / scale
    y_mean = y.mean(axis=0)
    gram = a.T @ a + ridge * len(a) * np.eye(a.shape[1])
    weights = np.linalg.solve(gram, a.T @ (y - y_mean))
    return b @ weights + y_mean


def r_squared(predicted: np.ndarray, actual: np.ndarray) -> float:
    """1 - SSE / SST of one quantity (NaN when ``actual`` is constant)."""
    predicted, actual = np.asarray(predicted, dtype=np.float64), np.asarray(actual, dtype=np.float64)
    total = float(np.sum((actual - actual.mean()) ** 2))
    return float("nan") if total == 0 else 1.0 - float(np.sum((actual - predicted) ** 2)) / total


def roc_auc(score: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve of ``score`` for the bool labels ``positive`` (ties count half; NaN with one
    class only): the probability that a positive frame scores above a negative one."""
    score, positive = np.asarray(score, dtype=np.float64), np.asarray(positive, dtype=bool)
    n_pos, n_neg = int(positive.sum()), int((~positive).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    order = np.argsort(score, kind="mergesort")
    _, start, count = np.unique(score[order], return_index=True, return_counts=True)
    ranks = np.empty(len(score))
    ranks[order] = np.repeat(start + (count + 1) / 2, count)  # 1-based ranks, ties averaged
    return (float(ranks[positive].sum()) - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg)


class _Probe:
    """One probed quantity's test-half predictions: ``predicted`` and ``actual`` over the test frames where
    ``on`` holds, scored by ``metric(predicted, actual)``."""

    def __init__(self, predicted: np.ndarray, actual: np.ndarray, on: np.ndarray, metric: Any) -> None:
        self.predicted, self.actual, self.on, self.metric = predicted, actual, on, metric

    def score(self, frames: np.ndarray | None = None) -> float:
        """The metric over every test frame, or over ``frames`` (indices into the test half, repeats kept)."""
        if frames is None:
            return float(self.metric(self.predicted, self.actual)) if self.on.any() else float("nan")
        position = np.cumsum(self.on) - 1  # test frame -> index into predicted / actual
        kept = frames[self.on[frames]]
        if not kept.size:
            return float("nan")
        return float(self.metric(self.predicted[position[kept]], self.actual[position[kept]]))


def _side_agreement(predicted: np.ndarray, actual: np.ndarray) -> float:
    return float(np.mean(np.sign(predicted) == np.sign(actual)))


def _feature_sets(frames: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    readings = (*LABELS, *READINGS, "head", "h_o")
    names = [k for k in frames if k not in readings and not k.startswith(KNOCKOUT_PREFIX)]
    if not names:
        raise ValueError("frames: expected at least one encoder's embeddings beside action / pose / target")
    sets = {name: frames[name] for name in names}
    sets["all"] = np.concatenate([frames[name] for name in names], axis=1)
    for hidden in ("head", "h_o"):
        if hidden in frames:
            sets[hidden] = frames[hidden]
    return sets


def _in_view(frames: Mapping[str, np.ndarray], max_range: float) -> np.ndarray:
    """bool ``[N]``: the target in the camera's cone within ``max_range`` metres (walls not checked)."""
    bearing = bearing_to(frames["pose"], frames["target"])
    distance = np.hypot(*(frames["target"][:, :2] - frames["pose"][:, :2]).T)
    return (np.abs(bearing) <= HALF_FIELD_OF_VIEW) & (distance <= max_range)


def _fit_probes(
    frames: Mapping[str, np.ndarray], ridge: float, max_range: float
) -> tuple[dict[str, dict[str, _Probe]], dict[str, np.ndarray]]:
    """``({features: {quantity: _Probe}}, {"fit", "test", "in_view"} bool masks over the frames)``."""
    fit = frames["trajectory"] % 2 == 0
    test = ~fit
    if not fit.any() or not test.any():
        raise ValueError("frames: the probes need frames of at least two trajectories")
    bearing = bearing_to(frames["pose"], frames["target"])
    in_view = _in_view(frames, max_range)
    every, seen_test = np.ones(int(test.sum()), dtype=bool), in_view[test]
    probes = {}
    for label, x in _feature_sets(frames).items():
        action = ridge_predict(x[fit], frames["action"][fit], x[test], ridge)
        seen = ridge_predict(x[fit], in_view[fit].astype(np.float64), x[test], ridge)
        probes[label] = {
            "angular": _Probe(action[:, 1], frames["action"][test, 1], every, r_squared),
            "linear": _Probe(action[:, 0], frames["action"][test, 0], every, r_squared),
            "in_view": _Probe(seen, in_view[test], every, roc_auc),
        }
        side, nothing = np.zeros(int(seen_test.sum())), np.zeros(int(test.sum()), dtype=bool)
        enough = (fit & in_view).sum() > x.shape[1] and seen_test.any()
        if enough:
            side = ridge_predict(x[fit & in_view], bearing[fit & in_view], x[test & in_view], ridge)
        for quantity, metric in (("bearing", r_squared), ("bearing_sign", _side_agreement)):
            probes[label][quantity] = _Probe(
                side, bearing[test & in_view], seen_test if enough else nothing, metric
            )
    return probes, {"fit": fit, "test": test, "in_view": in_view}


def _repeated_rows(frames: Mapping[str, np.ndarray]) -> set[str]:
    """Feature sets that repeat another: ``all`` of a one-encoder model, ``h_o`` of a head without THSC."""
    repeated = set()
    if len(_feature_sets(frames)) - ("head" in frames) - ("h_o" in frames) == 2:  # one encoder + all
        repeated.add("all")
    if "h_o" in frames and "head" in frames and np.array_equal(frames["h_o"], frames["head"]):
        repeated.add("h_o")
    return repeated


def probe_scores(
    frames: Mapping[str, np.ndarray], ridge: float = RIDGE, max_range: float = PROBE_RANGE
) -> dict[str, Any]:
    """The probes of :func:`frame_embeddings`' output: fitted on the frames of even-numbered trajectories,
    scored on the odd-numbered ones.

    Returns:
        ``{"frames": {"fit", "test", "in_view_test"}, "probes": {features: {quantity: value}}}`` for each
        encoder alone, ``all`` of them concatenated (with two encoders), and (when given) ``head`` and
        ``h_o`` (when it differs from ``head``: with THSC);
        quantities as in :data:`QUANTITIES` (NaN where the test half has no frame with its target in view);
        ``"target_reading"``: :func:`.target_reading.target_reading_summary` over all the frames (nothing
        is fitted), when the frames hold its readings; and ``"encoder_knockout"``:
        :func:`.knockout.knockout_summary`, when they hold the actions without each encoder.
    """
    probes, split = _fit_probes(frames, ridge, max_range)
    reading = target_reading_summary(frames, split["in_view"], max_range)
    knockout = knockout_summary(frames)
    return {
        "frames": {
            "fit": int(split["fit"].sum()),
            "test": int(split["test"].sum()),
            "in_view_test": int((split["test"] & split["in_view"]).sum()),
        },
        "probes": {
            label: {q: p.score() for q, p in quantities.items()}
            for label, quantities in probes.items()
            if label not in _repeated_rows(frames)
        },
        **({"target_reading": reading} if reading else {}),
        **({"encoder_knockout": knockout} if knockout else {}),
    }


def paired_probe_differences(
    frames: Mapping[str, np.ndarray],
    reference: Mapping[str, np.ndarray],
    features: tuple[str, ...] = ("all", "head", "h_o"),
    resamples: int = 1000,
    seed: int = 0,
    ridge: float = RIDGE,
    max_range: float = PROBE_RANGE,
) -> dict[str, dict[str, dict[str, float]]]:
    """Each probe of ``frames`` minus the same probe of ``reference`` (another model's
    :func:`frame_embeddings` of the same frames), with a 95 % interval from resampling whole test
    trajectories (the same resample for both models: a paired cluster bootstrap).

    Returns:
        ``{features: {quantity: {"difference", "low", "high"}}}`` for each of ``features`` both models have.

    Raises:
        ValueError: the two hold other frames (another dataset, seed or window).
    """
    for key in ("trajectory", "action", "pose"):
        if frames[key].shape != reference[key].shape or not np.array_equal(frames[key], reference[key]):
            raise ValueError(
                f"paired probes need the same frames: the two models' {key!r} differ (another dataset, "
                "seed or window)"
            )
    mine, _ = _fit_probes(frames, ridge, max_range)
    theirs, split = _fit_probes(reference, ridge, max_range)
    test_trajectory = frames["trajectory"][split["test"]]
    groups = [np.flatnonzero(test_trajectory == t) for t in np.unique(test_trajectory)]
    rng = np.random.default_rng(seed)
    draws = [
        np.concatenate([groups[i] for i in rng.integers(0, len(groups), len(groups))])
        for _ in range(resamples)
    ]
    out = {}
    for label in features:
        if label not in mine or label not in theirs:
            continue
        out[label] = {}
        for quantity in QUANTITIES:
            a, b = mine[label][quantity], theirs[label][quantity]
            spread = np.array([a.score(d) - b.score(d) for d in draws])
            spread = spread[np.isfinite(spread)]
            low, high = np.quantile(spread, [0.025, 0.975]) if spread.size else (float("nan"),) * 2
            out[label][quantity] = {
                "difference": a.score() - b.score(),
                "low": float(low),
                "high": float(high),
            }
    return out


def _cell(value: float) -> str:
    return "n/a" if value != value else f"{value:.3f}"


def probe_markdown(results: Mapping[str, Mapping[str, Any]], reference: str | None = None) -> str:
    """One table row per model and feature set of :func:`probe_scores` results ``{model label: result}``;
    with ``reference``, a second table of each other model's paired differences (``result["paired"]``)."""
    lines = [
        "| model | embedding | angular R² | linear R² | in view, AUC | bearing R² | bearing side |",
        "|---|---|---|---|---|---|---|",
    ]
    for label, result in results.items():
        for features, scores in result["probes"].items():
            lines.append(
                f"| {label} | {features} | " + " | ".join(_cell(scores[q]) for q in QUANTITIES) + " |"
            )
    first = next(iter(results.values()))["frames"]
    lines.append(
        f"\nFitted on {first['fit']:,} frames (even-numbered held-out trajectories), scored on "
        f"{first['test']:,} ({first['in_view_test']:,} with the target in the camera cone within "
        f"{PROBE_RANGE:g} m)."
    )
    paired = [(label, r["paired"]) for label, r in results.items() if r.get("paired")]
    if reference is not None and paired:
        lines += [
            f"\nMinus {reference}, paired on the same frames (95 % interval, test trajectories resampled):\n",
            "| model | embedding | angular R² | linear R² | in view, AUC | bearing R² | bearing side |",
            "|---|---|---|---|---|---|---|",
        ]
        for label, by_features in paired:
            for features, quantities in by_features.items():
                cells = [
                    f"{q['difference']:+.3f} [{q['low']:+.3f}, {q['high']:+.3f}]"
                    if q["difference"] == q["difference"]
                    else "n/a"
                    for q in (quantities[name] for name in QUANTITIES)
                ]
                lines.append(f"| {label} | {features} | " + " | ".join(cells) + " |")
    readings = {label: r["target_reading"] for label, r in results.items() if r.get("target_reading")}
    if readings:
        lines.append("\n" + target_reading_markdown(readings).rstrip("\n"))
    knockouts = {label: r["encoder_knockout"] for label, r in results.items() if r.get("encoder_knockout")}
    if knockouts:
        lines.append("\n" + knockout_markdown(knockouts).rstrip("\n"))
    return "\n".join(lines) + "\n"


def probe(
    models: Mapping[str, str | os.PathLike],
    exploration: str | os.PathLike,
    out_dir: str | os.PathLike,
    max_trajectories: int | None = None,
    seed: int = 0,
    device: str = "cpu",
    resamples: int = 1000,
    kind: str = "e",
) -> dict[str, Any]:
    """:func:`probe_scores` of each checkpoint of ``models`` (``{label: checkpoint}``) on the same held-out
    D_e (``kind="ca"``: D_ca) windows, and each later model's :func:`paired_probe_differences` against the
    first one, written to ``out_dir/probe.json`` and ``out_dir/probe.md``; returns the JSON's content.

    Every model reads windows of the shortest context among them (DT's 341 steps otherwise give it other
    windows of the long trajectories than NavFormer's 256), so all probes score the same frames.
    """
    from navformer_rl.training import checkpoint as ckpt

    if not models:
        raise ValueError("models: expected at least one LABEL CHECKPOINT pair")
    out = Path(out_dir)
    window = min(ckpt.load_policy_model(ckpt.resolve_checkpoint(c))[0].window_steps for c in models.values())
    frames = {
        label: frame_embeddings(
            checkpoint,
            exploration,
            max_trajectories,
            seed=seed,
            device=device,
            context_steps=window,
            kind=kind,
        )
        for label, checkpoint in models.items()
    }
    reference = next(iter(models))
    results = {}
    for label, embedded in frames.items():
        results[label] = probe_scores(embedded)
        if label != reference:
            results[label]["paired"] = paired_probe_differences(
                embedded, frames[reference], resamples=resamples, seed=seed
            )
    record = {
        "exploration": str(exploration),
        "kind": kind,
        "max_trajectories": max_trajectories,
        "seed": seed,
        "context_steps": window,
        "ridge": RIDGE,
        "probe_range": PROBE_RANGE,
        "resamples": resamples,
        "reference": reference,
        "checkpoints": {label: str(checkpoint) for label, checkpoint in models.items()},
        "results": results,
    }
    out.mkdir(parents=True, exist_ok=True)
    for name, text in (
        (PROBE_JSON, json.dumps(record, indent=2) + "\n"),
        (PROBE_MD, probe_markdown(results, reference)),
    ):
        partial = out / f".{name}.partial"
        partial.write_text(text)
        os.replace(partial, out / name)
    return record
