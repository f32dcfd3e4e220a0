"""The per-setup bar plot: the legend stays off the bars and their values;
missing intervals render cleanly."""

import csv
import io

import numpy as np
import pytest

from navformer_rl.evaluation.measures import RobotTrial
from navformer_rl.evaluation.plots import plot_setup_bars
from navformer_rl.evaluation.tables import (
    format_ratio,
    format_sr,
    summaries_to_csv,
    summarize_by_setup,
    table_markdown,
)

METHODS = {"navformer": 0.7, "dt": 0.5, "vrw": 0.0, "fca": 1.0}
NINE = [(size, n) for size in (7.5, 12.5, 17.5) for n in (2, 4, 6)]


def _records(setups, trials, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for method, p in METHODS.items():
        for size, n in setups:
            setup = f"{size:g}m-{n}r"
            for t in range(trials):
                for r in range(n):
                    ok = bool(rng.random() < p)
                    out.append(
                        RobotTrial(
                            method=method,
                            episode_id=f"{setup}-{t}",
                            setup=setup,
                            size=size,
                            n_robots=n,
                            world_seed=0,
                            trial=t,
                            robot=r,
                            robot_style="jackal",
                            measured=True,
                            success=ok,
                            success_step=50 if ok else None,
                            steps=50 if ok else 500,
                            collisions=int(rng.integers(0, 20)),
                            path_length=float(rng.uniform(5, 9)),
                            shortest_path=5.0,
                            shortest_path_to_disc=3.5,
                            final_distance=1.0 if ok else 4.0,
                        )  # fmt: skip
                    )
    return out


@pytest.fixture
def kept_figures(monkeypatch):
    """The figures plot_setup_bars makes, kept open for inspection (closed at the end)."""
    import matplotlib.pyplot as plt

    figures = []
    real_close = plt.close
    monkeypatch.setattr(plt, "close", lambda fig=None: figures.append(fig))
    yield figures
    for fig in figures:
        real_close(fig)


def _overlaps(a, b) -> bool:
    return a.x0 < b.x1 and b.x0 < a.x1 and a.y0 < b.y1 and b.y0 < a.y1


@pytest.mark.parametrize("setups", [NINE, NINE[:1]], ids=["4x9", "4x1"])
def test_the_legend_covers_no_bar_and_no_value(tmp_path, kept_figures, setups):
    # the legend used to sit inside the SR panel (upper right) and hid FCA's "100%" label
    path = plot_setup_bars(summarize_by_setup(_records(setups, 6)), tmp_path / "bars.png")
    assert path.stat().st_size > 0
    (fig,) = kept_figures
    renderer = fig.canvas.get_renderer()
    legends = [legend for ax in fig.axes if (legend := ax.get_legend()) is not None] + fig.legends
    assert len(legends) == 1
    box = legends[0].get_window_extent(renderer)
    assert [t.get_text() for t in legends[0].get_texts()] == sorted(METHODS)
    for ax in fig.axes:
        assert not _overlaps(box, ax.get_window_extent(renderer))  # outside every panel
        for text in ax.texts:
            assert not _overlaps(box, text.get_window_extent(renderer)), text.get_text()
    # nor under the title, and inside the figure
    assert not _overlaps(box, fig._suptitle.get_window_extent(renderer))
    assert fig.bbox.x0 <= box.x0 and box.x1 <= fig.bbox.x1 and box.y1 <= fig.bbox.y1
    # every value is written, inside its panel (SR of the 100 % bars included)
    sr_panel = fig.axes[0]
    assert len(sr_panel.texts) == len(METHODS) * len(setups)
    panel = sr_panel.get_window_extent(renderer)
    for text in sr_panel.texts:
        extent = text.get_window_extent(renderer)
        assert panel.y0 <= extent.y0 and extent.y1 <= panel.y1


def test_the_values_of_neighbouring_bars_do_not_overlap(tmp_path, kept_figures):
    plot_setup_bars(summarize_by_setup(_records(NINE, 6)), tmp_path / "bars.png")
    (fig,) = kept_figures
    renderer = fig.canvas.get_renderer()
    assert len(fig.axes) == 3  # SR, SPL, CR
    for ax in fig.axes:
        assert len(ax.texts) == len(METHODS) * len(NINE)  # every bar's value is written: 36 per panel
        boxes = sorted((t.get_window_extent(renderer) for t in ax.texts), key=lambda b: b.x0)
        for left, right in zip(boxes, boxes[1:]):
            assert left.x1 <= right.x0 + 0.5  # side by side, never on top of each other


def test_too_few_trials_render_as_no_interval(tmp_path, kept_figures):
    # one trial per setup: SPL / CR have no interval (NaN); SR's uses n_eff = 1 trial
    summaries = summarize_by_setup(_records([(7.5, 6), (12.5, 4)], 1))
    dt = next(s.metrics for s in summaries if s.method == "dt" and s.setup == "7.5m-6r")
    assert np.isnan(dt.spl_ci).all() and np.isnan(dt.cr_ci).all() and np.isfinite(dt.sr_ci).all()

    markdown = table_markdown(summaries)
    assert "[n/a]" in markdown and "nan" not in markdown
    assert format_ratio(0.5, (float("nan"), float("nan"))) == "0.500 [n/a]"
    assert format_sr(0.5, (float("nan"), float("nan"))) == "50.00% [n/a]"
    assert format_ratio(0.5, (0.25, 0.75)) == "0.500 [0.25, 0.75]" and format_ratio(0.5) == "0.500"

    text = summaries_to_csv(summaries)
    assert "nan" not in text.lower()
    row = next(
        r for r in csv.DictReader(io.StringIO(text)) if r["method"] == "dt" and r["setup"] == "7.5m-6r"
    )
    assert row["spl_low"] == row["spl_high"] == row["cr_low"] == row["cr_high"] == ""
    assert float(row["spl"]) == pytest.approx(dt.spl, abs=1e-6)
    assert float(row["sr_low"]) == pytest.approx(dt.sr_ci[0], abs=1e-6)

    path = plot_setup_bars(summaries, tmp_path / "bars.png")
    assert path.stat().st_size > 0
    (fig,) = kept_figures
    assert "too few trials" in fig.get_supxlabel()
    for ax in fig.axes:
        for text in ax.texts:  # every value label at a finite place
            assert np.isfinite(text.get_position()).all()
