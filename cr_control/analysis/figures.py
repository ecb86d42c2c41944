"""Figure helpers shared by cr_analyze and the chapter modules (matplotlib imported lazily)."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def column_figure(rows: int, height: float, sharex: bool = True):
    """A one-column figure of ``rows`` panels ``height`` inches tall; (figure, axes)."""
    from matplotlib.figure import Figure  # lazy: no plotting cost without figures

    fig = Figure(figsize=(7.5, 0.8 + height * rows), layout="constrained")
    return fig, fig.subplots(rows, 1, squeeze=False, sharex=sharex)[:, 0]


def save_figure(fig: Any, path: Path, written: list[Path]) -> None:
    """Grid, legends and PNG at 110 dpi; appends the path to ``written``."""
    for ax in fig.axes:
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize="small", loc="best")
    fig.savefig(path, dpi=110)
    written.append(path)
