"""The versions of the libraries that compute pointtraj's results.

Another version of OpenCV or numpy can round a value differently, the tracker then
decides differently from there on, and the figures move (the demo's trajectories were 1,516
with OpenCV 5.0.0 and 1,569 with 4.14.0). ``scripts/constraints.txt`` pins the versions the
documented figures were measured with, and every report names the ones it was made with.
"""

from __future__ import annotations

from importlib import metadata

__all__ = ["NUMERICAL_LIBRARIES", "library_versions"]

#: The libraries whose arithmetic the results depend on: each as the distributions that provide
#: it, the one pointtraj requires first (the names of ``scripts/constraints.txt``).
NUMERICAL_LIBRARIES: tuple[tuple[str, ...], ...] = (
    ("numpy",),
    ("scipy",),
    (
        "opencv-contrib-python-headless",
        "opencv-contrib-python",
        "opencv-python-headless",
        "opencv-python",
    ),
    ("open3d-cpu", "open3d"),
    ("pycolmap",),
    ("PyMaxflow",),
    ("onnxruntime", "onnxruntime-gpu"),
)


def library_versions() -> dict[str, str]:
    """The installed version of each numerical library, and of pointtraj itself.

    Returns
    -------
    dict of str to str
        ``{distribution: version}`` in the order of :data:`NUMERICAL_LIBRARIES` after
        ``pointtraj``; the first installed distribution of each library, or its required name
        with ``"not installed"``.
    """
    from . import __version__

    out = {"pointtraj": __version__}
    for names in NUMERICAL_LIBRARIES:
        for name in names:
            try:
                out[name] = metadata.version(name)
                break
            except metadata.PackageNotFoundError:
                continue
        else:
            out[names[0]] = "not installed"
    return out
