"""Label colours: the display colour of each class, and of each trajectory from its label."""

from __future__ import annotations

import colorsys
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..labelset import LabelSet

__all__ = [
    "UNLABELLED_COLOR",
    "label_colors",
    "class_palette",
    "person_palette",
    "blend_colors",
]

#: Colour of unlabelled trajectories (label -1).
UNLABELLED_COLOR = (128, 128, 128)


def label_colors(labels: np.ndarray, palette: np.ndarray) -> np.ndarray:
    """Per-trajectory RGB colours from labels.

    Parameters
    ----------
    labels : (M,) int ndarray
        Class index per trajectory; -1 (or any out-of-range value) is unlabelled.
    palette : (K, 3) uint8 ndarray
        Colour per class.

    Returns
    -------
    (M, 3) uint8 ndarray
    """
    labels = np.asarray(labels, dtype=np.int64)
    palette = np.asarray(palette, dtype=np.uint8)
    ok = (labels >= 0) & (labels < len(palette))
    out = np.empty((len(labels), 3), np.uint8)
    out[:] = UNLABELLED_COLOR
    out[ok] = palette[labels[ok]]
    return out


def class_palette(class_names: Sequence[str], label_set: LabelSet | None = None) -> np.ndarray:
    """Display colour of each class, looked up by name.

    Parameters
    ----------
    class_names : sequence of K str
        Classes in class-index order (for example ``labels.npz`` ``class_names``).
    label_set : LabelSet, optional
        The capture's label set (``labels.toml``). Names it lacks take the colour of
        :meth:`LabelSet.default`, else a distinct generated colour.

    Returns
    -------
    (K, 3) uint8 ndarray
    """
    from ..labelset import LabelSet

    sets = [s for s in (label_set, LabelSet.default()) if s is not None]
    out = np.empty((len(class_names), 3), np.uint8)
    for k, name in enumerate(class_names):
        for s in sets:
            if name in s.names:
                out[k] = s.colors[s.names.index(name)]
                break
        else:
            # Golden-ratio hues: distinct, deterministic colours for unknown classes.
            r, g, b = colorsys.hsv_to_rgb((0.13 + 0.618034 * k) % 1.0, 0.75, 0.9)
            out[k] = np.rint(np.array([r, g, b]) * 255)
    return out


def person_palette(count: int) -> np.ndarray:
    """A distinct colour per person (instance id 0 .. count-1), for ``color_by = "instance"``.

    Parameters
    ----------
    count : int
        Number of people.

    Returns
    -------
    (count, 3) uint8 ndarray
        Saturated golden-ratio hues, the same for the same id in every render.

    Examples
    --------
    >>> person_palette(2).tolist()
    [[230, 57, 57], [57, 108, 230]]
    """
    out = np.empty((int(count), 3), np.uint8)
    for i in range(int(count)):
        r, g, b = colorsys.hsv_to_rgb((0.618034 * i) % 1.0, 0.75, 0.9)
        out[i] = np.rint(np.array([r, g, b]) * 255)
    return out


def blend_colors(colors: np.ndarray, target: np.ndarray, weight: np.ndarray | float) -> np.ndarray:
    """Move colours towards a target colour: ``colors + weight (target - colors)``, rounded.

    Parameters
    ----------
    colors : (S, 3) uint8 ndarray
    target : (3,) array-like
        RGB in 0..255.
    weight : (S,) float ndarray or float
        0 keeps a colour, 1 gives the target.

    Returns
    -------
    (S, 3) uint8 ndarray
    """
    c = np.asarray(colors, np.float64)
    w = np.asarray(weight, np.float64)
    if w.ndim == 1:
        w = w[:, None]
    return np.rint(c + (np.asarray(target, np.float64) - c) * w).astype(np.uint8)
