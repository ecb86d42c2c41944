"""Figures of a sweep: a line per metric for one varied parameter, a heatmap for two.

Written to DIR/plots/<metric>.png for each plotted metric: the SPEC's ``metrics``, else those
of :data:`DEFAULT_METRICS` the table has. A list-valued input is plotted by its first element
(the axis label says so). Points that stopped, diverged or failed are drawn as red crosses on the
line (at the axis bottom) and left blank (hatched) in a heatmap; a random sweep of two
parameters is a scatter coloured by the metric. More than two varied parameters: no figure.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from cr_control.analysis.figures import save_figure

DEFAULT_METRICS = ("pos_err_rms_last_half_m", "pos_err_max_m", "settling_time_s",
                   "f_err_x_rms_N", "f_err_y_rms_N", "normal_force_err_rms_last_half_N",
                   "path_err_rms_last_half_m", "contact_lost_s")


def _scalar(value: Any) -> float:
    if isinstance(value, (list, tuple)):
        return float(value[0]) if value else math.nan
    return float(value)


def _label(name: str, values: list[Any]) -> str:
    return f"{name} (first element)" if any(isinstance(v, (list, tuple)) for v in values) else name


def _log_scale(x: np.ndarray) -> bool:
    x = x[np.isfinite(x)]
    return bool(len(x) and x.min() > 0 and x.max() / x.min() >= 20)


def plotted_metrics(names: list[str], wanted: list[str] | None) -> list[str]:
    """The metrics to plot, of the table's columns ``names``."""
    return [m for m in (wanted or DEFAULT_METRICS) if m in names]


def plot(out: Path, names: list[str], table: list[dict[str, Any]], inputs: list[str],
         wanted: list[str] | None, grid: bool) -> list[Path]:
    """Write the figures (see the module docstring); return their paths."""
    # lazy: no plotting cost where no figure is drawn
    from matplotlib.figure import Figure

    if not table or not 1 <= len(inputs) <= 2:
        return []
    folder = out / "plots"
    folder.mkdir(exist_ok=True)
    ok = np.array([row["status"] == "ok" for row in table])
    written: list[Path] = []
    for metric in plotted_metrics(names, wanted):
        y = np.array([row[metric] for row in table], dtype=float)
        y[~np.isfinite(y)] = np.nan         # an infinite metric is not drawn (nor breaks the axes)
        fig = Figure(figsize=(6.5, 4.2), layout="constrained")
        ax = fig.subplots()
        bad = int((~ok).sum())
        title = metric + (f"  ({bad} stopped/diverged/failed)" if bad else "")
        if len(inputs) == 1:
            values = [row[inputs[0]] for row in table]
            x = np.array([_scalar(v) for v in values])
            order = np.argsort(x, kind="stable")
            shown = np.where(ok, y, np.nan)
            ax.plot(x[order], shown[order], "o-", label=metric)
            if bad:
                low = np.nanmin(shown) if np.isfinite(shown).any() else 0.0
                ax.plot(x[~ok], np.full(bad, low), "x", color="red", label="stopped/diverged/failed")
            ax.set_xlabel(_label(inputs[0], values))
            ax.set_ylabel(metric)
            if _log_scale(x):
                ax.set_xscale("log")
            if _log_scale(shown):
                ax.set_yscale("log")
        else:
            a = [row[inputs[0]] for row in table]
            b = [row[inputs[1]] for row in table]
            xa, xb = np.array([_scalar(v) for v in a]), np.array([_scalar(v) for v in b])
            z = np.where(ok, y, np.nan)
            if grid:
                ua, ub = sorted(set(xa.tolist())), sorted(set(xb.tolist()))
                image = np.full((len(ub), len(ua)), np.nan)
                for i, j, v in zip(xa, xb, z, strict=True):
                    image[ub.index(j), ua.index(i)] = v
                ax.patch.set(hatch="xx", edgecolor="red")
                mesh = ax.pcolormesh(np.arange(len(ua) + 1), np.arange(len(ub) + 1),
                                     np.ma.masked_invalid(image), cmap="viridis")
                ax.set_xticks(np.arange(len(ua)) + 0.5, [f"{v:.3g}" for v in ua])
                ax.set_yticks(np.arange(len(ub)) + 0.5, [f"{v:.3g}" for v in ub])
                middle = np.nanmean([np.nanmin(image), np.nanmax(image)]) \
                    if np.isfinite(image).any() else 0.0
                for (r, c), v in np.ndenumerate(image):
                    if np.isfinite(v):
                        ax.text(c + 0.5, r + 0.5, f"{v:.3g}", ha="center", va="center",
                                fontsize="x-small", color="black" if v > middle else "white")
                ax.grid(False)
            else:
                mesh = ax.scatter(xa, xb, c=z, cmap="viridis")
                if bad:
                    ax.plot(xa[~ok], xb[~ok], "x", color="red", label="stopped/diverged/failed")
                if _log_scale(xa):
                    ax.set_xscale("log")
                if _log_scale(xb):
                    ax.set_yscale("log")
            fig.colorbar(mesh, ax=ax, label=metric)
            ax.set_xlabel(_label(inputs[0], a))
            ax.set_ylabel(_label(inputs[1], b))
        ax.set_title(title, fontsize="medium")
        save_figure(fig, folder / f"{metric}.png", written)
    return written
