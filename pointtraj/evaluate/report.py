"""The evaluation report: ``report/index.md``, PNG plots and a flat ``report/metrics.json``.

Every section shows the paper's published figures beside ours (:mod:`pointtraj.evaluate.paper`).
The plotting functions take plain numbers, so any study can call them.
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..atomic import atomic_path, write_text_atomic
from . import paper

__all__ = [
    "Section",
    "write_report",
    "plot_temporal",
    "plot_disagreement",
    "plot_validity",
    "plot_confusion",
    "temporal_table",
]

logger = logging.getLogger(__name__)


@dataclass
class Section:
    """One section of the report.

    Attributes
    ----------
    title : str
    body : str
        Markdown.
    figures : list of str
        PNG file names (relative to the report folder).
    """

    title: str
    body: str
    figures: list[str] = field(default_factory=list)


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: str | os.PathLike) -> None:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, bbox_inches="tight")
    _plt().close(fig)


def _clean(value):
    """JSON-safe value: NaN and infinities become None, numpy scalars Python ones."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_report(
    folder: str | os.PathLike, title: str, sections: Sequence[Section], metrics: Mapping
) -> Path:
    """Write ``index.md`` and ``metrics.json`` into ``folder`` (atomically).

    Parameters
    ----------
    folder : path-like
        The report folder (created); plots named in the sections must already be there.
    title : str
    sections : sequence of Section
    metrics : mapping
        Flat ``{"dotted.key": number}`` figures (a few are lists of strings, e.g.
        ``health.warnings``).

    Returns
    -------
    pathlib.Path
        Path of ``index.md``.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    lines = [f"# {title}", ""]
    for s in sections:
        lines += [f"## {s.title}", "", s.body.strip(), ""]
        for fig in s.figures:
            lines += [f"![{s.title}]({fig})", ""]
    write_text_atomic(folder / "index.md", "\n".join(lines))
    clean = {k: _clean(v) for k, v in sorted(metrics.items())}
    write_text_atomic(folder / "metrics.json", json.dumps(clean, indent=2) + "\n")
    return folder / "index.md"


def temporal_table(ours: Mapping[str, Mapping[int, tuple[float, float, int]]]) -> str:
    """Markdown table of the temporal-consistency study, ours beside the paper's Table 1.

    Parameters
    ----------
    ours : mapping
        ``{pooling: {seconds: (mean, std, n)}}``.

    Returns
    -------
    str
        One row per pooling of ours, then the paper's rows (:data:`paper.TEMPORAL_NC`), at
        the union of the lags (``n/a`` where ours has no figure).
    """
    secs = sorted({s for d in ours.values() for s in d} | set(paper.TEMPORAL_NC["view"]))
    head = "| pooling | " + " | ".join(f"{s} s" for s in secs) + " |"
    rows = [head, "|" + "---|" * (len(secs) + 1)]
    for name, d in ours.items():
        cells = []
        for s in secs:
            m = d.get(s, (float("nan"), float("nan"), 0))
            cells.append("n/a" if not math.isfinite(m[0]) else f"{m[0]:.2f} ± {m[1]:.2f}")
        rows.append(f"| ours, {name} | " + " | ".join(cells) + " |")
    for name, d in paper.TEMPORAL_NC.items():
        cells = [f"{d[s][0]:.2f} ± {d[s][1]:.2f}" if s in d else "" for s in secs]
        rows.append(f"| paper, {name} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def plot_temporal(
    ours: Mapping[str, Mapping[int, tuple[float, float, int]]], path: str | os.PathLike
) -> None:
    """Normalised correlation against time, ours (solid) and the paper's (dashed)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4))
    colors = {
        "view": "tab:blue",
        "view_soft": "tab:cyan",
        "average": "tab:orange",
        "average_visible": "tab:brown",
        "max": "tab:green",
        "product": "tab:red",
    }
    for name, d in ours.items():
        s = sorted(d)
        m = np.array([d[k][0] for k in s], float)
        e = np.array([d[k][1] for k in s], float)
        ax.errorbar(
            s, m, yerr=e, marker="o", color=colors.get(name), label=f"ours, {name}", capsize=3
        )
    for name, d in paper.TEMPORAL_NC.items():
        s = sorted(d)
        ax.plot(
            s, [d[k][0] for k in s], "--", color=colors.get(name), alpha=0.7, label=f"paper, {name}"
        )
    ax.set_xlabel("time after the first frame (s)")
    ax.set_ylabel("normalised correlation")
    ax.set_ylim(0, 1.05)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Temporal consistency of the 3D semantic map")
    _save(fig, path)


def plot_disagreement(
    bins: np.ndarray, curves: Mapping[str, np.ndarray], path: str | os.PathLike
) -> None:
    """Label disagreement of neighbour pairs against their distance (the paper's Figure 6).

    Parameters
    ----------
    bins : (B + 1,) float ndarray
        Distance bin edges, metres.
    curves : mapping
        ``{name: (B,) fraction of pairs with different labels}``.
    path : path-like
    """
    plt = _plt()
    centers = (np.asarray(bins[:-1]) + np.asarray(bins[1:])) / 2
    fig, ax = plt.subplots(figsize=(6, 4))
    for name, frac in curves.items():
        ax.plot(centers * 100, frac, marker="o", label=name)
    ax.set_xlabel("distance between the pair (cm)")
    ax.set_ylabel("fraction of pairs with different labels")
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(
        "Affinity effectiveness (paper: ε_s degrades after 10 cm, SE(3) holds to 1 m)", fontsize=9
    )
    _save(fig, path)


def plot_validity(
    cameras: Sequence[int], curves: Mapping[str, Sequence[float]], path: str | os.PathLike
) -> None:
    """Predictive validity against the number of labelling cameras (the paper's Figure 7)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 4))
    for name, vals in curves.items():
        ax.plot(list(cameras), list(vals), marker="o", label=name)
    ax.axhline(0.6, color="grey", ls=":", label="paper: > 0.6 at 20 cameras")
    ax.set_xlabel("cameras used for labelling")
    ax.set_ylabel("agreement with held-out recognition")
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Predictive validity on held-out cameras")
    _save(fig, path)


def plot_confusion(
    confusion: np.ndarray, class_names: Sequence[str], path: str | os.PathLike, title: str = ""
) -> None:
    """Row-normalised confusion matrix (true classes in rows)."""
    plt = _plt()
    c = np.asarray(confusion, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        norm = c / c.sum(axis=1, keepdims=True)
    k = len(class_names)
    fig, ax = plt.subplots(figsize=(0.45 * k + 2, 0.45 * k + 1.5))
    im = ax.imshow(norm, cmap="Blues", vmin=0, vmax=1)
    ax.set_xticks(range(k), class_names, rotation=90, fontsize=7)
    ax.set_yticks(range(k), class_names, fontsize=7)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    fig.colorbar(im, ax=ax, fraction=0.046)
    ax.set_title(title, fontsize=9)
    _save(fig, path)
