"""The recogniser interface: an image goes in, per-pixel class confidences come out.

A recogniser produces L2D (the paper's Section 4.1): an array of shape (h, w, K) with values in
[0, 1], one channel per class of the label set, possibly coarser than the image. Sampling maps an
image pixel (u, v) to ``((u + 0.5) * w / W - 0.5, (v + 0.5) * h / H - 0.5)`` in the map.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np

__all__ = ["Recognizer", "ImageContext"]


@dataclass(frozen=True)
class ImageContext:
    """Where an image comes from, for recognisers that need more than pixels.

    Attributes
    ----------
    camera : str
        Camera name.
    frame : int
        Frame index.
    capture : str or None
        Capture folder (the simulated recogniser reads ground truth from it).
    """

    camera: str
    frame: int
    capture: str | None = None


class Recognizer(abc.ABC):
    """Base class of 2D recognisers.

    Subclasses set :attr:`name` and :attr:`class_names` (the K label-set classes whose
    confidences they output, in channel order) and implement :meth:`recognize`.
    """

    #: Registry name, as used by ``--recognizer``.
    name: str = ""
    #: The K classes of the output channels (names from labels.toml).
    class_names: tuple[str, ...] = ()

    @abc.abstractmethod
    def recognize(self, image: np.ndarray, context: ImageContext | None = None) -> np.ndarray:
        """Per-pixel class confidences for one image.

        Parameters
        ----------
        image : (H, W, 3) uint8 ndarray
            RGB image.
        context : ImageContext, optional
            Camera, frame and capture of the image.

        Returns
        -------
        (h, w, K) float32 ndarray
            Confidences in [0, 1]; h <= H and w <= W.
        """

    def recognize_people(
        self, image: np.ndarray, context: ImageContext | None = None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Class confidences and, where the recogniser tells people apart, a person-id map.

        The semantics stage samples the person-id map at the trajectories' projections; the
        labelling stage's instances (:mod:`pointtraj.instances`) vote with it. Ids are per
        image: person 0 of one image need not be person 0 of another.

        Parameters
        ----------
        image : (H, W, 3) uint8 ndarray
        context : ImageContext, optional

        Returns
        -------
        L2D : (h, w, K) float32 ndarray
            As :meth:`recognize`.
        people : (h', w') int16 ndarray or None
            Person id per cell (0, 1, ...; -1 where no person), on its own grid (sampled like
            L2D); None (the default) when the recogniser gives no person masks.
        """
        return self.recognize(image, context), None
