"""The metrics of the iterations since the last log row (:class:`LogWindow`), summarised into that row."""

from __future__ import annotations

from collections.abc import Mapping


class LogWindow:
    """The metrics of the iterations since the last log row, summarised into the next one.

    Every metric is averaged over the iterations that reported it - ``loss_dt_exploration`` over the D_e
    iterations only, ``loss_dt_collision_avoidance`` over the D_ca ones, so an even ``logger.log_interval``
    still logs both tasks; ``frames_per_s`` is the window's frames over its seconds; ``lr``, ``lr_dve`` and
    ``tau`` are the logged iteration's own values. Part of the resume state, so a resumed run logs the same
    rows as an uninterrupted one whatever the checkpoint and log intervals.
    """

    LAST_VALUE_KEYS = ("lr", "lr_dve", "tau")

    def __init__(self) -> None:
        self._sums: dict[str, float] = {}
        self._counts: dict[str, int] = {}
        self._last: dict[str, float] = {}

    def __len__(self) -> int:
        """Iterations in the window."""
        return self._counts.get("loss", 0)

    def add(self, metrics: Mapping[str, float]) -> None:
        """Add one iteration's metrics (the dict of :meth:`Trainer.step`)."""
        for key, value in metrics.items():
            if key in self.LAST_VALUE_KEYS:
                self._last[key] = float(value)
            else:
                self._sums[key] = self._sums.get(key, 0.0) + float(value)
                self._counts[key] = self._counts.get(key, 0) + 1

    def pop_row(self) -> dict[str, float]:
        """The summarised row (empty for an empty window); the window starts over."""
        row = {key: total / self._counts[key] for key, total in self._sums.items()}
        if self._sums.get("iteration_s", 0.0) > 0.0 and "frames" in self._sums:
            row["frames_per_s"] = self._sums["frames"] / self._sums["iteration_s"]
        row.update(self._last)
        self.__init__()
        return row

    def state_dict(self) -> dict[str, dict]:
        """``{"sums": {metric: float}, "counts": {metric: int}, "last": {metric: float}}`` (plain containers,
        ``weights_only``-safe in ``resume.pt``)."""
        return {"sums": dict(self._sums), "counts": dict(self._counts), "last": dict(self._last)}

    def load_state_dict(self, state: Mapping[str, Mapping]) -> None:
        """Inverse of :meth:`state_dict`."""
        self._sums = {str(k): float(v) for k, v in state["sums"].items()}
        self._counts = {str(k): int(v) for k, v in state["counts"].items()}
        self._last = {str(k): float(v) for k, v in state["last"].items()}
