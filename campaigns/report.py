"""Reducing run rows to tables: means over successful runs, Markdown, plots."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from rfhoming.host.outputs import save_figure

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure


def mean(rows: Iterable[dict[str, Any]], key: str, digits: int = 3) -> float | None:
    values = [r[key] for r in rows if r.get(key) is not None]
    return round(float(np.mean(values)), digits) if values else None


def table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    def cell(v: Any) -> str:
        return "–" if v is None else f"{v:g}" if isinstance(v, float) else str(v)

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def failed_runs(failures: list[dict[str, Any]], describe: Callable[[dict[str, Any]], str]) -> str:
    """A Markdown paragraph naming each failed run, or nothing when none failed."""
    if not failures:
        return ""
    return "\n\nFailed runs: " + "; ".join(f"{describe(r)} ({r['final_error_m']} m after {r['time_s']} s)"
                                            for r in failures)


def figure(path: Path, panels: int, width: float = 4.0) -> tuple[Figure, Any]:
    """A matplotlib figure with ``panels`` axes side by side, non-interactive backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, panels, figsize=(width * panels, 3.6), squeeze=False)
    return fig, axes[0]


def save(fig: Figure, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    save_figure(fig, path, dpi=110)  # replaced whole: a failed plot leaves the old one
    plt.close(fig)


def grouped_bars(ax: Axes, groups: Sequence[str], series: dict[str, Sequence[float | None]], title: str) -> None:
    """One bar per series in each group; a missing value draws no bar."""
    width = 0.8 / max(len(series), 1)
    x = np.arange(len(groups))
    for i, (label, values) in enumerate(series.items()):
        v = np.array([np.nan if a is None else a for a in values], dtype=float)
        ax.bar(x + (i - (len(series) - 1) / 2) * width, v, width, label=label)
    ax.set_xticks(x, groups)
    ax.set_title(title)
    ax.grid(axis="y", alpha=0.3)
