"""Dense multi-view correspondences at one time instant (paper Section 5, step 2).

Per image we detect many ORB features spread over a grid, match them by brute-force Hamming
distance along the edges of the camera connectivity graph, keep the matches that grid-based
motion statistics (GMS, Bian et al. 2017) supports, and drop those that violate the known epipolar
geometry. Pairwise matches are chained into multi-view tracks with a connected-components pass
over the (camera, keypoint) graph; the result is an observation array ``(C, N, 2)`` with NaN where
a camera does not see track ``n``, ready for ``triangulate_ransac``.

A track that holds two keypoints of the same camera is ambiguous: :func:`resolve_ambiguous`
keeps, per camera, the keypoint closest to the triangulated point.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..camera import CameraRig
from ..errors import ValidationError, check_array
from ..geometry import finite_rows, pixel_distance, undistort_normalized

__all__ = [
    "MatchingConfig",
    "Features",
    "MultiViewTracks",
    "detect_features",
    "match_pair",
    "hamming_nearest",
    "match_pairs",
    "epipolar_distances",
    "build_tracks",
    "resolve_ambiguous",
    "match_frame",
]

logger = logging.getLogger(__name__)


#: GMS ``thresholdFactor`` where the rig does not call for a lenient one.
GMS_THRESHOLD = 6.0


@dataclass(frozen=True)
class MatchingConfig:
    """Parameters of the per-frame dense matching.

    Attributes
    ----------
    num_features : int
        Features kept per image after the grid spreading (the paper-scale setting is 10^4 or more
        per 1280x1024 image).
    oversample : float
        ORB detects ``oversample * num_features`` candidates before the grid keeps the strongest
        ones of each cell.
    fast_threshold : int
        FAST threshold of ORB's detector; low values give many features on weak texture.
    grid_cells : (int, int)
        Columns and rows of the spreading grid; each cell keeps at most
        ``num_features / (cols * rows)`` features.
    pyramid_levels : int
        ORB pyramid levels (scale factor 1.2).
    patch_size : int
        ORB patch size (and border) in pixels; larger patches are more distinctive.
    upright : bool
        Describe every keypoint at angle 0 instead of its intensity-centroid orientation: more
        distinctive for rigs of upright cameras (about twice the GMS matches on the synthetic
        rings); turn off for rolled cameras.
    gms_threshold : float or None
        GMS ``thresholdFactor``: the higher, the fewer matches survive. None (the default, the
        key left out): chosen from the rig by the reconstruction
        (:meth:`~.config.ReconstructConfig.for_rig`: 2 on rigs of at most 8 cameras with large
        images, :data:`GMS_THRESHOLD` elsewhere); functions given this config directly read
        None as :data:`GMS_THRESHOLD`.
    gms_rotation, gms_scale : bool
        Let GMS search over rotations / scales (off for rigs of upright cameras).
    cross_check : bool
        Keep only mutual nearest neighbours (before GMS; in both directions of guided matching).
    epipolar_px : float
        Maximum distance (pixels, in undistorted coordinates, the larger of the two directions)
        between a keypoint and the epipolar line of its match.
    guided : bool or None
        None (the default, the key left out): chosen from the rig by the reconstruction
        (:meth:`~.config.ReconstructConfig.for_rig`: on where the images are large (0.6 MP and
        more) over the
        image or the cameras have close partners, off elsewhere); functions given this config
        directly read None as off. Epipolar-guided matching: each keypoint is compared only with the keypoints of the other
        image within ``epipolar_px`` of its epipolar line (known calibration), with Lowe's ratio
        test. Far more matches across wide baselines than unguided nearest neighbours, and
        about 3 times faster than brute force (0.044 s against 0.13 s a pair of 6,500-feature
        1280x1024 images), but the nearest neighbour in a band is a weaker test than the global
        one: on repeated textures (the synthetic floor) it lets through wrong matches that two
        views cannot reject, so it is off on the demo's rig.
    ratio : float
        Ratio test of guided matching (best / second-best Hamming distance).
    gms : bool
        Filter the putative matches with GMS (always on for unguided matching).
    """

    num_features: int = 12000
    oversample: float = 3.0
    fast_threshold: int = 5
    grid_cells: tuple[int, int] = (16, 12)
    pyramid_levels: int = 4
    patch_size: int = 31
    upright: bool = True
    gms_threshold: float | None = None
    gms_rotation: bool = False
    gms_scale: bool = False
    cross_check: bool = False
    epipolar_px: float = 2.5
    guided: bool | None = None
    ratio: float = 0.8
    gms: bool = True

    def __post_init__(self) -> None:
        if self.num_features < 10:
            raise ValidationError(f"num_features must be at least 10, got {self.num_features}")
        if self.oversample < 1:
            raise ValidationError(f"oversample must be >= 1, got {self.oversample}")
        if self.patch_size < 5:
            raise ValidationError(f"patch_size must be at least 5, got {self.patch_size}")
        if min(self.grid_cells) < 1:
            raise ValidationError(f"grid_cells must be positive, got {self.grid_cells}")
        if self.epipolar_px <= 0 or (self.gms_threshold is not None and self.gms_threshold <= 0):
            raise ValidationError("epipolar_px and gms_threshold must be positive")
        if not 0 < self.ratio <= 1:
            raise ValidationError(f"ratio must be in (0, 1], got {self.ratio}")


@dataclass(frozen=True)
class Features:
    """Keypoints and binary descriptors of one image.

    Attributes
    ----------
    pixels : (F, 2) float32 ndarray
        Keypoint positions (distorted pixels).
    descriptors : (F, 32) uint8 ndarray
        ORB descriptors.
    keypoints : list of cv2.KeyPoint
        The same keypoints as OpenCV objects (GMS needs their scale and angle).
    size : (int, int)
        Image ``(width, height)``.
    """

    pixels: np.ndarray
    descriptors: np.ndarray
    keypoints: list
    size: tuple[int, int]

    def __len__(self) -> int:
        return int(self.pixels.shape[0])


@dataclass(frozen=True)
class MultiViewTracks:
    """Pairwise matches chained into tracks over the (camera, keypoint) graph.

    Attributes
    ----------
    node_camera : (V,) int64 ndarray
        Camera of each node (a keypoint that took part in at least one match).
    node_track : (V,) int64 ndarray
        Track of each node, in ``0 .. N-1``.
    node_pixels : (V, 2) float64 ndarray
        Keypoint position of each node.
    node_degree : (V,) int64 ndarray
        Number of matches the node took part in.
    observations : (C, N, 2) float64 ndarray
        One observation per camera and track, NaN where the camera is absent. Where a track holds
        several keypoints of one camera, the one with the most matches.
    ambiguous : (N,) bool ndarray
        Tracks with several keypoints in one camera.
    """

    node_camera: np.ndarray
    node_track: np.ndarray
    node_pixels: np.ndarray
    node_degree: np.ndarray
    observations: np.ndarray
    ambiguous: np.ndarray

    @property
    def num_tracks(self) -> int:
        """N."""
        return int(self.observations.shape[1])


def detect_features(
    image: np.ndarray,
    config: MatchingConfig | None = None,
    boxes: np.ndarray | None = None,
) -> Features:
    """ORB features spread over a grid.

    Parameters
    ----------
    image : (H, W, 3) uint8 RGB or (H, W) uint8 grey ndarray
    config : MatchingConfig, optional
    boxes : (B, 4) int ndarray, optional
        Detect only inside these boxes ``(x0, y0, x1, y1)`` (pixels, end exclusive), each with
        its share of the image's ORB budget by area; a keypoint in an earlier box is not taken
        again from a later one. The descriptors are computed on the whole image. Default: the
        whole image.

    Returns
    -------
    Features
        At most ``config.num_features`` keypoints; each grid cell keeps its strongest ones.
    """
    import cv2

    cfg = config or MatchingConfig()
    img = np.asarray(image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
        raise ValidationError(
            f"image: expected (H, W, 3) or (H, W) uint8, got {img.shape} {img.dtype}"
        )
    grey = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
    h, w = grey.shape
    budget = cfg.num_features * cfg.oversample

    def orb_for(share: float):
        return cv2.ORB_create(
            nfeatures=max(1, int(budget * share)),
            scaleFactor=1.2,
            nlevels=cfg.pyramid_levels,
            edgeThreshold=cfg.patch_size,
            patchSize=cfg.patch_size,
            fastThreshold=cfg.fast_threshold,
        )

    orb = orb_for(1.0)
    if boxes is None:
        kps = orb.detect(grey, None)
    else:
        kps = _detect_in_boxes(grey, boxes, orb_for)
    if kps:
        pts = cv2.KeyPoint_convert(kps)  # (F0, 2)
        response = np.array([k.response for k in kps], dtype=np.float64)
        gx, gy = cfg.grid_cells
        cx = np.clip((pts[:, 0] * gx / w).astype(np.int64), 0, gx - 1)
        cy = np.clip((pts[:, 1] * gy / h).astype(np.int64), 0, gy - 1)
        cell = cy * gx + cx
        order = np.lexsort((-response, cell))  # strongest first within each cell
        sorted_cell = cell[order]
        starts = np.searchsorted(sorted_cell, sorted_cell, side="left")
        rank = np.arange(order.size) - starts
        per_cell = max(1, int(np.ceil(cfg.num_features / (gx * gy))))
        keep = np.sort(order[rank < per_cell])
        kps = [kps[i] for i in keep]
    if cfg.upright:
        for k in kps:
            k.angle = 0.0
    kps, desc = orb.compute(grey, kps)
    if desc is None or not kps:
        return Features(np.zeros((0, 2), np.float32), np.zeros((0, 32), np.uint8), [], (w, h))
    pixels = cv2.KeyPoint_convert(kps).astype(np.float32).reshape(-1, 2)
    return Features(pixels, desc, list(kps), (w, h))


def _detect_in_boxes(grey: np.ndarray, boxes: np.ndarray, orb_for) -> list:
    """ORB keypoints detected in boxes of a grey image (:func:`detect_features`'s ``boxes``),
    in full-image coordinates."""
    import cv2

    h, w = grey.shape
    b = np.asarray(boxes, np.int64).reshape(-1, 4)
    b[:, [0, 2]] = np.clip(b[:, [0, 2]], 0, w)
    b[:, [1, 3]] = np.clip(b[:, [1, 3]], 0, h)
    kps: list = []
    for i, (x0, y0, x1, y1) in enumerate(b.tolist()):
        if x1 <= x0 or y1 <= y0:
            continue
        found = orb_for((x1 - x0) * (y1 - y0) / (w * h)).detect(grey[y0:y1, x0:x1], None)
        if not found:
            continue
        pts = cv2.KeyPoint_convert(found).reshape(-1, 2).astype(np.float64) + (x0, y0)
        x, y = pts[:, 0, None], pts[:, 1, None]
        e = b[None, :i]  # (1, i, 4): a keypoint in an earlier box was taken there
        taken = np.any(
            (x >= e[..., 0]) & (x < e[..., 2]) & (y >= e[..., 1]) & (y < e[..., 3]), axis=1
        )
        for k, (u, v), t in zip(found, pts.tolist(), taken.tolist(), strict=True):
            if not t:
                k.pt = (u, v)
                kps.append(k)
    return kps


def moving_boxes(
    pixels: np.ndarray,
    moving: np.ndarray,
    sizes: np.ndarray,
    tile_px: int = 64,
    min_points: int = 5,
    min_share: float = 0.25,
) -> list[np.ndarray]:
    """Per camera, the boxes around the image regions where tracked points move.

    The image is cut into square tiles. A tile moves when at least ``min_points`` of the points
    observed in it moved, and at least ``min_share`` of them (so that tracking jitter, which
    flags a few scattered points of a still surface, moves no tile). The moving tiles and their
    8 neighbours (a tile of margin: where the moving surface uncovers new surface) are split
    into connected regions, each given as its bounding box.

    Parameters
    ----------
    pixels : (C, N, 2) float ndarray
        The tracked points' observations (NaN where a camera does not observe a point).
    moving : (N,) bool ndarray
        Which points moved.
    sizes : (C, 2) int ndarray
        Image ``(width, height)`` per camera.
    tile_px : int
    min_points : int
    min_share : float

    Returns
    -------
    list of C (B_c, 4) int64 ndarrays
        Boxes ``(x0, y0, x1, y1)`` in pixels (end exclusive, within the image); B_c may be 0.
    """
    import cv2

    pix = check_array("pixels", pixels, (None, None, 2))
    mov = check_array("moving", moving, (pix.shape[1],), dtype=bool)
    out = []
    for c in range(pix.shape[0]):
        w, h = (int(v) for v in sizes[c])
        gw, gh = -(-w // tile_px), -(-h // tile_px)
        ok = finite_rows(pix[c])
        ij = np.floor(pix[c, ok] / tile_px).astype(np.int64)
        inside = (ij[:, 0] >= 0) & (ij[:, 0] < gw) & (ij[:, 1] >= 0) & (ij[:, 1] < gh)
        cell = ij[inside, 1] * gw + ij[inside, 0]
        total = np.bincount(cell, minlength=gw * gh)
        moved = np.bincount(cell, weights=mov[ok][inside], minlength=gw * gh)
        tiles = (moved >= min_points) & (moved >= min_share * np.maximum(total, 1))
        if not tiles.any():
            out.append(np.zeros((0, 4), np.int64))
            continue
        grid = cv2.dilate(tiles.reshape(gh, gw).astype(np.uint8), np.ones((3, 3), np.uint8))
        n, _, stats, _ = cv2.connectedComponentsWithStats(grid, connectivity=8)
        s = stats[1:n, :4].astype(np.int64) * tile_px  # (B, 4) x, y, width, height
        boxes = np.column_stack([s[:, 0], s[:, 1], s[:, 0] + s[:, 2], s[:, 1] + s[:, 3]])
        boxes[:, [0, 2]] = np.clip(boxes[:, [0, 2]], 0, w)
        boxes[:, [1, 3]] = np.clip(boxes[:, [1, 3]], 0, h)
        out.append(boxes)
    return out


def epipolar_distances(
    rig: CameraRig, cam_a: int, cam_b: int, pixels_a: np.ndarray, pixels_b: np.ndarray
) -> np.ndarray:
    """Symmetric point-to-epipolar-line distance of putative matches, in undistorted pixels.

    Parameters
    ----------
    rig : CameraRig
    cam_a, cam_b : int
        Camera indices.
    pixels_a, pixels_b : (N, 2) float ndarray
        Matched distorted pixels in camera ``a`` and ``b``.

    Returns
    -------
    (N,) float ndarray
        ``max(d_b, d_a)``, where ``d_b`` is the distance of ``x_b`` to the epipolar line of
        ``x_a`` in image b (scaled by b's focal length), and vice versa.
    """
    pa = check_array("pixels_a", pixels_a, (None, 2))
    pb = check_array("pixels_b", pixels_b, (pa.shape[0], 2))
    return _epipolar_distances(
        rig, cam_a, cam_b, _normalized(rig, cam_a, pa), _normalized(rig, cam_b, pb)
    )


def _epipolar_distances(
    rig: CameraRig, cam_a: int, cam_b: int, xa: np.ndarray, xb: np.ndarray
) -> np.ndarray:
    """:func:`epipolar_distances` of undistorted normalised coordinates ``xa``, ``xb`` (N, 2)."""
    line_b, hb, scale_a, scale_b = _epipolar_terms(rig, cam_a, cam_b, xa, xb)
    alg = np.abs(np.sum(line_b * hb, axis=1))  # (N,) |x_b^T E x_a|
    with np.errstate(invalid="ignore"):  # 0 * inf at an epipole: NaN, as 0 / 0 was
        return alg * np.fmax(scale_a, scale_b)


def _essential(rig: CameraRig, cam_a: int, cam_b: int) -> np.ndarray:
    """(3, 3) essential matrix with ``x_b^T E x_a = 0`` in normalised coordinates."""
    R = rig.R[cam_b] @ rig.R[cam_a].T
    t = rig.R[cam_b] @ (rig.C[cam_a] - rig.C[cam_b])
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return tx @ R


def _epipolar_terms(
    rig: CameraRig, cam_a: int, cam_b: int, xa: np.ndarray, xb: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-keypoint terms of the symmetric epipolar distance (:func:`epipolar_distances`).

    For keypoints ``xa`` (Na, 2) of a and ``xb`` (Nb, 2) of b (undistorted normalised), the
    distance of a pair ``(i, j)`` is ``|line_b[i] . hb[j]| * max(scale_a[i], scale_b[j])``:
    ``line_b`` (Na, 3) are a's epipolar lines in b, ``hb`` (Nb, 3) b's homogeneous
    coordinates, ``scale_a`` (Na,) b's focal length over the norm of a's line (the distance in
    b) and ``scale_b`` (Nb,) a's focal length over the norm of b's line in a (the distance in a).
    """
    E = _essential(rig, cam_a, cam_b)
    ha = np.concatenate([xa, np.ones((len(xa), 1))], axis=1)  # (Na, 3)
    hb = np.concatenate([xb, np.ones((len(xb), 1))], axis=1)  # (Nb, 3)
    line_b = ha @ E.T  # (Na, 3) lines in image b
    line_a = hb @ E  # (Nb, 3) lines in image a
    with np.errstate(divide="ignore"):
        scale_a = rig.K[cam_b, 0, 0] / np.hypot(line_b[:, 0], line_b[:, 1])
        scale_b = rig.K[cam_a, 0, 0] / np.hypot(line_a[:, 0], line_a[:, 1])
    return line_b, hb, scale_a, scale_b


def _normalized(rig: CameraRig, cam: int, pixels: np.ndarray) -> np.ndarray:
    K = rig.K[cam]
    y = (pixels[:, 1] - K[1, 2]) / K[1, 1]
    x = (pixels[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return undistort_normalized(np.stack([x, y], axis=-1), rig.dist[cam])


def hamming_nearest(
    queries: np.ndarray, train: np.ndarray, *, cross_check: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Each query descriptor's nearest train descriptor by Hamming distance (exact).

    The answer of OpenCV's ``BFMatcher(NORM_HAMMING, crossCheck).match``, the first of equally
    near train descriptors included, at about a third of its CPU time on ORB descriptors: the
    distances are popcounts of 64-bit words, summed in uint8 over blocks of queries against
    every train descriptor (:func:`_nearest_words`; ``docs/reconstruction.md``, "Brute-force
    matching in numpy").

    Parameters
    ----------
    queries : (N, B) uint8 ndarray
        Binary descriptors, ``B`` bytes each (ORB: 32).
    train : (M, B) uint8 ndarray
    cross_check : bool
        Keep only the mutual nearest neighbours: query ``i``'s nearest ``j`` whose own nearest
        query is ``i``.

    Returns
    -------
    pairs : (Q, 2) int64 ndarray
        ``(query, train)`` indices, in query order; every query when ``cross_check`` is off.
    distance : (Q,) int64 ndarray
        Their Hamming distances in bits.
    """
    q, t = np.asarray(queries), np.asarray(train)
    if (
        q.ndim != 2
        or t.ndim != 2
        or q.shape[1] != t.shape[1]
        or q.dtype != np.uint8
        or t.dtype != np.uint8
    ):
        raise ValidationError(
            f"hamming_nearest: descriptors must be (N, B) and (M, B) uint8, got {q.shape} "
            f"{q.dtype} and {t.shape} {t.dtype}"
        )
    if len(q) == 0 or len(t) == 0:
        return np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
    qw, tw = _words(q), _words(t)
    j, d = _nearest_words(qw, tw)
    i = np.arange(len(q))
    if cross_check:
        mutual = _nearest_words(tw, qw)[0][j] == i
        i, j, d = i[mutual], j[mutual], d[mutual]
    return np.column_stack([i, j]), d


def _words(descriptors: np.ndarray) -> np.ndarray:
    """(N, B) uint8 descriptors as (N, ceil(B / 8)) uint64 words, zero-padded (ORB: 4 words;
    also the guided matcher's, :func:`_camera_terms`)."""
    n, b = descriptors.shape
    padded = np.zeros((n, -(-b // 8) * 8), np.uint8)
    padded[:, :b] = descriptors
    return padded.view(np.uint64)


def _nearest_words(a: np.ndarray, b: np.ndarray, block: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Each row of ``a``'s nearest row of ``b`` by Hamming distance, the first of equals.

    Parameters
    ----------
    a : (N, W) uint64 ndarray
    b : (M, W) uint64 ndarray
    block : int
        Rows of ``a`` per pass: the (block, M) temporaries stay in cache (64 x 5,500 words of
        8 bytes: 2.8 MB).

    Returns
    -------
    index : (N,) int64 ndarray
    distance : (N,) int64 ndarray
        In bits.
    """
    n, w = a.shape
    bt = np.ascontiguousarray(b.T)  # (W, M): each word of every b row, contiguous
    acc = np.uint8 if w <= 4 else np.uint16  # 4 words: at most 256 bits, 256 reads as 0
    xor = np.empty((block, len(b)), np.uint64)
    count = np.empty((block, len(b)), np.uint8)
    dist = np.empty((block, len(b)), acc)
    out = np.empty(n, np.int64)
    for s in range(0, n, block):
        rows = a[s : s + block]
        k = len(rows)
        x, c, d = xor[:k], count[:k], dist[:k]
        np.bitwise_xor(rows[:, :1], bt[0], out=x)
        np.bitwise_count(x, out=c)
        d[...] = c
        for word in range(1, w):
            np.bitwise_xor(rows[:, word : word + 1], bt[word], out=x)
            np.bitwise_count(x, out=c)
            np.add(d, c, out=d)
        out[s : s + k] = d.argmin(axis=1)
    dist_out = np.bitwise_count(a ^ b[out]).sum(axis=1, dtype=np.int64)
    if w == 4:  # a distance of 256 wrapped to 0 in uint8 and was taken: redo those rows
        for r in np.flatnonzero(dist_out == 256).tolist():  # all 256 bits differ: next to never
            row = np.bitwise_count(a[r] ^ b).sum(axis=1, dtype=np.int64)
            out[r] = row.argmin()
            dist_out[r] = row[out[r]]
    return out, dist_out


def _dmatches(pairs: np.ndarray, distance: np.ndarray) -> list:
    """``cv2.DMatch`` objects for GMS from (Q, 2) index pairs and (Q,) distances."""
    import cv2

    p = np.asarray(pairs)
    d = np.asarray(distance, np.float64)
    return list(map(cv2.DMatch, p[:, 0].tolist(), p[:, 1].tolist(), d.tolist()))


def match_pair(
    rig: CameraRig,
    cam_a: int,
    cam_b: int,
    features_a: Features,
    features_b: Features,
    config: MatchingConfig | None = None,
    *,
    terms: tuple[_CameraTerms, _CameraTerms] | None = None,
) -> np.ndarray:
    """Brute-force Hamming matches filtered by GMS and the epipolar constraint.

    Parameters
    ----------
    rig : CameraRig
    cam_a, cam_b : int
        Camera indices of the two images.
    features_a, features_b : Features
    config : MatchingConfig, optional
    terms : (_CameraTerms, _CameraTerms), optional
        The two cameras' per-image terms (:func:`_camera_terms`); :func:`match_frame` computes
        them once per image instead of once per pair. The result is the same.

    Returns
    -------
    (Q, 2) int64 ndarray
        Keypoint indices ``(i_a, i_b)`` of the surviving matches.
    """
    import cv2

    cfg = config or MatchingConfig()
    if len(features_a) < 2 or len(features_b) < 2:
        return np.zeros((0, 2), np.int64)
    if cfg.guided:
        if terms is None:
            terms = (_camera_terms(rig, cam_a, features_a), _camera_terms(rig, cam_b, features_b))
        pairs, dist = _guided_matches(rig, cam_a, cam_b, features_a, features_b, cfg, terms=terms)
        raw = _dmatches(pairs, dist)
    else:
        pairs, dist = hamming_nearest(
            features_a.descriptors, features_b.descriptors, cross_check=cfg.cross_check
        )
        raw = _dmatches(pairs, dist)
    if not raw:
        return np.zeros((0, 2), np.int64)
    good = raw
    if cfg.gms or not cfg.guided:
        good = cv2.xfeatures2d.matchGMS(
            features_a.size,
            features_b.size,
            features_a.keypoints,
            features_b.keypoints,
            raw,
            withRotation=cfg.gms_rotation,
            withScale=cfg.gms_scale,
            thresholdFactor=GMS_THRESHOLD if cfg.gms_threshold is None else cfg.gms_threshold,
        )
    if not good:
        return np.zeros((0, 2), np.int64)
    pairs = np.array([(m.queryIdx, m.trainIdx) for m in good], dtype=np.int64)  # (Q, 2)
    if terms is not None:  # the same values, element by element
        d = _epipolar_distances(rig, cam_a, cam_b, terms[0].x[pairs[:, 0]], terms[1].x[pairs[:, 1]])
    else:
        d = epipolar_distances(
            rig, cam_a, cam_b, features_a.pixels[pairs[:, 0]], features_b.pixels[pairs[:, 1]]
        )
    keep = d <= cfg.epipolar_px
    logger.debug(
        "pair %d-%d: %d putative, %d GMS, %d epipolar",
        cam_a,
        cam_b,
        len(raw),
        len(pairs),
        keep.sum(),
    )
    return pairs[keep]


@dataclass(frozen=True)
class _CameraTerms:
    """Per-camera quantities of guided matching, computed once per image and reused by every
    pair the camera takes part in.

    Attributes
    ----------
    x : (F, 2) float64 ndarray
        Undistorted normalised coordinates of the keypoints.
    h : (F, 3) float64 ndarray
        The same, homogeneous.
    rays : (F, 3) float64 ndarray
        Unit world directions of the keypoints' rays.
    words : (4, F) uint64 ndarray
        The descriptors as four 64-bit words, one contiguous row per word.
    """

    x: np.ndarray
    h: np.ndarray
    rays: np.ndarray
    words: np.ndarray


def _camera_terms(rig: CameraRig, cam: int, features: Features) -> _CameraTerms:
    """:class:`_CameraTerms` of one camera's features."""
    x = _normalized(rig, cam, features.pixels.astype(np.float64))
    h = np.concatenate([x, np.ones((len(x), 1))], axis=1)  # (F, 3)
    d = h @ rig.R[cam]  # (F, 3) = (R^T h)^T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return _CameraTerms(x, h, d, np.ascontiguousarray(_words(features.descriptors).T))


def _epipolar_angles(rays: np.ndarray, basis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Epipolar-plane angle and the sine of the ray's angle to the baseline, per keypoint.

    Every epipolar plane of a camera pair contains the baseline ``u``; its normal
    ``u × d`` (``d`` the world direction of a keypoint's ray) is the same for the two rays of a
    3D point, so matching keypoints share the angle of that normal about ``u``.

    Parameters
    ----------
    rays : (N, 3) float ndarray
        Unit world directions of the keypoints' rays (:class:`_CameraTerms`).
    basis : (3, 3) float ndarray
        Rows ``u, e1, e2``: the unit baseline and two unit vectors orthogonal to it.

    Returns
    -------
    phi : (N,) float ndarray
        Angle in (-π, π].
    sin_theta : (N,) float ndarray
        Sine of the angle between the ray and the baseline.
    """
    n = np.cross(basis[0], rays)  # (N, 3), |n| = sin(theta)
    return np.arctan2(n @ basis[2], n @ basis[1]), np.linalg.norm(n, axis=1)


_POS_BITS = 32  # candidate positions in the low bits of a (distance, position) sort key


def _guided_matches(
    rig: CameraRig,
    cam_a: int,
    cam_b: int,
    features_a: Features,
    features_b: Features,
    cfg: MatchingConfig,
    chunk: int = 1024,
    margin: float = 1.25,
    max_window: float = 0.05,
    terms: tuple[_CameraTerms, _CameraTerms] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Nearest neighbours within the epipolar band, with the ratio test (vectorised).

    Keypoints of b are sorted by their epipolar-plane angle (:func:`_epipolar_angles`); each
    keypoint of a looks at those within an angular window of ``margin`` times ``epipolar_px``
    over the focal length, divided by the sine of its ray's angle to the baseline (a pixel
    subtends at most about ``1 / f``; at most ``max_window`` radians, so keypoints near the
    epipole get no more candidates than that), and compares its descriptor with those that
    pass :func:`epipolar_distances`' test exactly (``max(d_a, d_b) <= epipolar_px``, computed
    from per-keypoint epipolar lines). A keypoint's candidates are a contiguous run of b's
    sorted keypoints, so b's per-keypoint terms are laid out in that order once and read in
    runs, and a's are repeated rather than gathered. Hamming distances are popcounts of 64-bit
    words; the nearest (the first of equals in the run) and second nearest per keypoint come
    from ``minimum.reduceat`` over (distance, position) keys (no sort). With
    ``cfg.cross_check`` only mutual nearest neighbours within the bands are kept.

    Parameters
    ----------
    rig : CameraRig
    cam_a, cam_b : int
    features_a, features_b : Features
    cfg : MatchingConfig
    chunk : int
        Keypoints of a per batch (bounds the candidate arrays).
    margin, max_window : float
        The search window (above).
    terms : (_CameraTerms, _CameraTerms), optional
        The two cameras' terms (:func:`_camera_terms`), when the caller keeps them per image.

    Returns
    -------
    pairs : (Q, 2) int64 ndarray
        Keypoint indices ``(i_a, i_b)``.
    distance : (Q,) int64 ndarray
        Hamming distances.
    """
    Ca, Cb = rig.C[cam_a], rig.C[cam_b]
    u = Cb - Ca
    base = float(np.linalg.norm(u))
    if base < 1e-12:  # no baseline: no epipolar geometry
        return np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
    u = u / base
    e1 = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    basis = np.stack([u, e1, np.cross(u, e1)])
    ta, tb = terms or (
        _camera_terms(rig, cam_a, features_a),
        _camera_terms(rig, cam_b, features_b),
    )
    phi_a, sin_a = _epipolar_angles(ta.rays, basis)
    phi_b, _ = _epipolar_angles(tb.rays, basis)
    # search window: the band's angular half-width seen from a (a pixel subtends about 1 / f)
    tol_a = cfg.epipolar_px / rig.K[cam_a, 0, 0] / np.maximum(sin_a, 1e-6)
    window = np.minimum(margin * tol_a, max_window)
    # exact band test per candidate (epipolar_distances' terms, per keypoint)
    E = _essential(rig, cam_a, cam_b)
    line_b = ta.h @ E.T  # (Na, 3) a's epipolar lines in image b
    line_a = tb.h @ E  # (Nb, 3) b's epipolar lines in image a
    with np.errstate(divide="ignore"):
        scale_a = rig.K[cam_b, 0, 0] / np.hypot(line_b[:, 0], line_b[:, 1])
        scale_b = rig.K[cam_a, 0, 0] / np.hypot(line_a[:, 0], line_a[:, 1])
    nb = phi_b.size
    order = np.argsort(phi_b)
    # b's terms in angle order; wrap around ±π with copies shifted by ∓2π on either side
    ext_phi = np.concatenate([phi_b[order] - 2 * np.pi, phi_b[order], phi_b[order] + 2 * np.pi])
    ext_idx = np.tile(order, 3)
    ext_x = np.tile(tb.x[order, 0], 3)
    ext_y = np.tile(tb.x[order, 1], 3)
    ext_scale = np.tile(scale_b[order], 3)
    ext_words = np.tile(tb.words[:, order], 3)  # (4, 3 Nb)
    la = [np.ascontiguousarray(line_b[:, k]) for k in range(3)]
    words_a = ta.words
    eps = cfg.epipolar_px
    low = (1 << _POS_BITS) - 1
    big = np.iinfo(np.int64).max
    out_a, out_b, out_d, mutual_cand = [], [], [], []
    for s in range(0, phi_a.size, chunk):  # bounded candidate arrays
        lo = np.searchsorted(ext_phi, phi_a[s : s + chunk] - window[s : s + chunk], side="left")
        hi = np.searchsorted(ext_phi, phi_a[s : s + chunk] + window[s : s + chunk], side="right")
        cnt = hi - lo
        nz = np.flatnonzero(cnt > 0)
        if nz.size == 0:
            continue
        rows = s + nz
        cnt, lo = cnt[nz], lo[nz]
        total = int(cnt.sum())
        starts = np.cumsum(cnt) - cnt
        pos = np.repeat(lo - starts, cnt) + np.arange(total)  # (T,) into the ext arrays
        # inside the band in both images: max(d_a, d_b) <= epipolar_px. The products are summed
        # in einsum's order ((l0 x + l2) + l1 y, hb's last entry being 1): the same bits.
        alg = np.repeat(la[0][rows], cnt) * ext_x[pos]
        alg += np.repeat(la[2][rows], cnt)
        alg += np.repeat(la[1][rows], cnt) * ext_y[pos]
        np.abs(alg, out=alg)
        with np.errstate(invalid="ignore"):  # 0 * inf at an epipole: NaN, outside
            alg *= np.fmax(np.repeat(scale_a[rows], cnt), ext_scale[pos])
        inside = alg <= eps
        own = np.repeat(rows, cnt)[inside]
        pos = pos[inside]
        if own.size == 0:
            continue
        grp_start = np.flatnonzero(np.r_[True, own[1:] != own[:-1]])  # (G,) one group per a
        grp_cnt = np.diff(np.r_[grp_start, own.size])
        acc = np.bitwise_count(words_a[0][own] ^ ext_words[0][pos])  # uint8, <= 64 each
        for k in (1, 2):
            acc += np.bitwise_count(words_a[k][own] ^ ext_words[k][pos])
        dist = acc.astype(np.int64)  # <= 256 with the last word
        dist += np.bitwise_count(words_a[3][own] ^ ext_words[3][pos])
        # (distance, position) keys: the minimum is the nearest, the first of equals
        if own.size >= 1 << _POS_BITS:  # cannot happen below ~1M keypoints per image
            raise ValidationError(f"guided matching: {own.size} candidates in one chunk")
        key = dist << _POS_BITS
        key |= np.arange(own.size)
        best_key = np.minimum.reduceat(key, grp_start)  # (G,)
        best = best_key >> _POS_BITS
        best_pos = best_key & low
        if cfg.cross_check:
            mutual_cand.append((own, ext_idx[pos], dist))
        key[best_pos] = big  # the second nearest without the first
        second = np.minimum.reduceat(key, grp_start) >> _POS_BITS
        keep = (grp_cnt == 1) | (best < cfg.ratio * second)
        sel = best_pos[keep]
        out_a.append(own[sel])
        out_b.append(ext_idx[pos[sel]])
        out_d.append(best[keep])
    if not out_a:
        return np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
    pairs = np.stack([np.concatenate(out_a), np.concatenate(out_b)], axis=1)
    best_dist = np.concatenate(out_d)
    if cfg.cross_check and pairs.size:
        # mutual: the b keypoint's nearest a keypoint within the bands is the same
        own = np.concatenate([c[0] for c in mutual_cand])
        trn = np.concatenate([c[1] for c in mutual_cand])
        dist = np.concatenate([c[2] for c in mutual_cand])
        ob = np.lexsort((dist, trn))
        head = ob[np.r_[True, trn[ob][1:] != trn[ob][:-1]]]
        back = np.full(nb, -1, np.int64)
        back[trn[head]] = own[head]
        mutual = back[pairs[:, 1]] == pairs[:, 0]
        pairs, best_dist = pairs[mutual], best_dist[mutual]
    return pairs, best_dist


def build_tracks(
    num_cameras: int,
    features: list[Features],
    pair_cameras: np.ndarray,
    pair_matches: list[np.ndarray],
) -> MultiViewTracks:
    """Chain pairwise matches into multi-view tracks (connected components).

    Parameters
    ----------
    num_cameras : int
        C.
    features : list of C Features
    pair_cameras : (E, 2) int ndarray
        Camera indices of each matched pair.
    pair_matches : list of E (Q_e, 2) int ndarrays
        Keypoint indices of the matches of each pair (see :func:`match_pair`).

    Returns
    -------
    MultiViewTracks
        Tracks with at least two distinct cameras.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if len(features) != num_cameras:
        raise ValidationError(f"features: expected {num_cameras} entries, got {len(features)}")
    pair_cameras = check_array("pair_cameras", pair_cameras, (len(pair_matches), 2), dtype=np.int64)
    counts = np.array([len(f) for f in features], dtype=np.int64)
    base = np.concatenate([[0], np.cumsum(counts)])  # node id = base[c] + keypoint
    src = [base[a] + m[:, 0] for (a, _), m in zip(pair_cameras, pair_matches)]
    dst = [base[b] + m[:, 1] for (_, b), m in zip(pair_cameras, pair_matches)]
    src = np.concatenate(src) if src else np.zeros(0, np.int64)
    dst = np.concatenate(dst) if dst else np.zeros(0, np.int64)
    total = int(base[-1])
    empty = MultiViewTracks(
        np.zeros(0, np.int64),
        np.zeros(0, np.int64),
        np.zeros((0, 2)),
        np.zeros(0, np.int64),
        np.full((num_cameras, 0, 2), np.nan),
        np.zeros(0, bool),
    )
    if src.size == 0:
        return empty
    graph = coo_matrix((np.ones(src.size, np.int8), (src, dst)), shape=(total, total)).tocsr()
    _, comp = connected_components(graph, directed=True, connection="weak")
    degree = np.bincount(src, minlength=total) + np.bincount(dst, minlength=total)
    nodes = np.flatnonzero(degree > 0)  # (V,)
    node_cam = np.searchsorted(base, nodes, side="right") - 1
    node_comp = comp[nodes]
    # tracks need >= 2 distinct cameras
    cam_comp = np.unique(np.stack([node_comp, node_cam], axis=1), axis=0)  # distinct (comp, cam)
    ncam = np.bincount(cam_comp[:, 0], minlength=total)
    keep = ncam[node_comp] >= 2
    nodes, node_cam, node_comp = nodes[keep], node_cam[keep], node_comp[keep]
    if nodes.size == 0:
        return empty
    uniq, node_track = np.unique(node_comp, return_inverse=True)
    N = uniq.size
    pix_all = np.concatenate([f.pixels for f in features]).astype(np.float64)  # (total, 2)
    node_pix = pix_all[nodes]
    node_deg = degree[nodes]
    # one node per (track, camera): the one with the most matches
    order = np.lexsort((nodes, -node_deg, node_cam, node_track))
    key = node_track[order] * num_cameras + node_cam[order]
    first = np.concatenate([[True], key[1:] != key[:-1]])
    chosen = order[first]
    obs = np.full((num_cameras, N, 2), np.nan)
    obs[node_cam[chosen], node_track[chosen]] = node_pix[chosen]
    per_track = np.bincount(node_track, minlength=N)
    distinct = np.bincount(node_track[chosen], minlength=N)
    return MultiViewTracks(
        node_camera=node_cam,
        node_track=node_track,
        node_pixels=node_pix,
        node_degree=node_deg,
        observations=obs,
        ambiguous=per_track > distinct,
    )


def resolve_ambiguous(rig: CameraRig, tracks: MultiViewTracks, points: np.ndarray) -> np.ndarray:
    """Per track and camera, the keypoint closest to the track's triangulated point.

    Parameters
    ----------
    rig : CameraRig
    tracks : MultiViewTracks
    points : (N, 3) float ndarray
        A first triangulation of ``tracks.observations`` (NaN where it failed).

    Returns
    -------
    (C, N, 2) float ndarray
        Observations where each ambiguous (track, camera) takes the node with the smallest
        reprojection error; tracks whose point is NaN keep their first choice.
    """
    X = check_array("points", points, (tracks.num_tracks, 3))
    obs = tracks.observations.copy()
    amb_nodes = np.flatnonzero(tracks.ambiguous[tracks.node_track])
    if amb_nodes.size == 0:
        return obs
    cam = tracks.node_camera[amb_nodes]
    trk = tracks.node_track[amb_nodes]
    proj = rig.project(X[np.unique(trk)])
    col = np.searchsorted(np.unique(trk), trk)
    err = pixel_distance(proj.pixels[cam, col], tracks.node_pixels[amb_nodes])  # (V',)
    err = np.where(np.isfinite(err), err, np.inf)
    order = np.lexsort((err, cam, trk))
    key = trk[order] * len(rig) + cam[order]
    first = np.concatenate([[True], key[1:] != key[:-1]])
    best = order[first]
    ok = np.isfinite(err[best])
    obs[cam[best][ok], trk[best][ok]] = tracks.node_pixels[amb_nodes[best[ok]]]
    return obs


def match_pairs(
    rig: CameraRig,
    features: Sequence[Features],
    edges: np.ndarray,
    config: MatchingConfig | None = None,
) -> list[np.ndarray]:
    """:func:`match_pair` over camera pairs, each image's guided-matching terms computed once.

    Brute-force pairs (``cfg.guided`` off) are matched on as many threads as OpenCV uses
    (:func:`_brute_force_threads`); the result is the same on any number.

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    features : sequence of C Features
    edges : (E, 2) int ndarray
        Camera pairs.
    config : MatchingConfig, optional

    Returns
    -------
    list of E (Q_e, 2) int64 ndarrays
        Each pair's matches, as :func:`match_pair` returns them.
    """
    cfg = config or MatchingConfig()
    terms: dict[int, _CameraTerms] = {}
    if cfg.guided:  # once per image, not once per pair (undistortion, rays, descriptor words)
        terms = {
            int(c): _camera_terms(rig, int(c), features[c])
            for c in np.unique(edges)
            if len(features[c]) >= 2
        }

    def one(pair: list[int]) -> np.ndarray:
        a, b = pair
        pair_terms = (terms[a], terms[b]) if a in terms and b in terms else None
        return match_pair(rig, a, b, features[a], features[b], cfg, terms=pair_terms)

    pairs = np.asarray(edges, dtype=np.int64).reshape(-1, 2).tolist()
    threads = 1 if cfg.guided else min(_brute_force_threads(), len(pairs))
    if threads > 1:  # numpy and GMS release the GIL; the pairs come back in order
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(threads, thread_name_prefix="match") as pool:
            return list(pool.map(one, pairs))
    return [one(p) for p in pairs]


def _brute_force_threads() -> int:
    """Threads for brute-force pair matching: OpenCV's (the cores, or 1 in a one-thread Dask
    worker, where the worker process is the core: ``executor._one_thread_opencv``)."""
    import cv2

    return max(1, cv2.getNumThreads())


#: Cells (of the radius) beyond which :func:`near_pixels` asks a k-d tree instead: 4 M int64
#: cell starts are 32 MB; paper69's 1280x1024 images at 1.5 px are 0.6 M cells.
_NEAR_MAX_CELLS = 1 << 22


def near_pixels(pixels: np.ndarray, queries: np.ndarray, radius_px: float) -> np.ndarray:
    """Which queries lie within ``radius_px`` of one of ``pixels`` (strictly nearer).

    The pixels are binned in square cells a little larger than the radius, so that a pixel
    near a query lies in one of the 3 x 3 cells around the query's; only those are compared,
    by the squared distance ``dx * dx + dy * dy < radius_px ** 2`` in float64. That is the test
    of ``scipy.spatial.cKDTree.query(..., distance_upper_bound=radius_px)``, which this
    replaces and falls back on where the queries span more than :data:`_NEAR_MAX_CELLS`
    cells (the same answers, ``tests/reconstruct/test_matching.py``); building the tree cost
    most of the query on a paper69 camera (45,000 pixels: 30 of 40 ms).

    Parameters
    ----------
    pixels : (Q, 2) float ndarray
        Pixels of one image (NaN rows are ignored).
    queries : (M, 2) float ndarray
        Pixels of the same image (NaN rows are never near).
    radius_px : float

    Returns
    -------
    (M,) bool ndarray
    """
    ok = finite_rows(queries)
    near = np.zeros(len(queries), bool)
    pts = np.asarray(pixels, np.float64)
    pts = pts[finite_rows(pts)]
    if len(pts) == 0 or not ok.any() or not radius_px > 0:
        return near
    q = np.asarray(queries, np.float64)[ok]
    cell = radius_px * (1 + 1e-9)  # a pixel nearer than the radius is in a neighbouring cell
    with np.errstate(over="ignore"):  # pixels near the float range: inf cells, the tree
        qx, qy = np.floor(q[:, 0] / cell), np.floor(q[:, 1] / cell)
    x0, x1, y0, y1 = qx.min() - 1, qx.max() + 1, qy.min() - 1, qy.max() + 1
    if not (x1 - x0 + 1) * (y1 - y0 + 1) <= _NEAR_MAX_CELLS:  # (inf beyond float range)
        from scipy.spatial import cKDTree

        d, _ = cKDTree(pts).query(q, k=1, distance_upper_bound=radius_px)
        near[np.flatnonzero(ok)] = np.isfinite(d)
        return near
    ny = int(y1 - y0 + 1)
    cells = int(x1 - x0 + 1) * ny
    with np.errstate(over="ignore"):
        px, py = np.floor(pts[:, 0] / cell), np.floor(pts[:, 1] / cell)
    inside = (px >= x0) & (px <= x1) & (py >= y0) & (py <= y1)  # the others are near no query
    pts = pts[inside]
    key = ((px[inside] - x0) * ny + (py[inside] - y0)).astype(np.int64)  # cell, column-major
    pts = pts[np.argsort(key)]
    start = np.zeros(cells + 1, np.int64)  # the sorted pixels of cell k: start[k]:start[k + 1]
    np.cumsum(np.bincount(key, minlength=cells), out=start[1:])
    qkey = ((qx - x0) * ny + (qy - y0)).astype(np.int64)
    r2 = radius_px * radius_px
    hit = np.zeros(len(q), bool)
    for dx in (-1, 0, 1):  # each neighbouring column's three cells are contiguous
        col = qkey + dx * ny
        a, n = start[col - 1], start[col + 2] - start[col - 1]
        rows = np.flatnonzero((n > 0) & ~hit)
        if rows.size == 0:
            continue
        reps = n[rows]
        qi = np.repeat(rows, reps)
        pi = np.repeat(a[rows] - (np.cumsum(reps) - reps), reps) + np.arange(qi.size)
        d = q[qi] - pts[pi]
        hit[qi[d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] < r2]] = True
    near[np.flatnonzero(ok)] = hit
    return near


def without_near(features: Features, pixels: np.ndarray, radius_px: float) -> Features:
    """The features farther than ``radius_px`` from every one of ``pixels``.

    Parameters
    ----------
    features : Features
        F keypoints of one image.
    pixels : (Q, 2) float ndarray
        Pixels of the same image (distorted; NaN rows are ignored).
    radius_px : float

    Returns
    -------
    Features
        The kept keypoints, in their order, with their descriptors.
    """
    pts = check_array("pixels", pixels, (None, 2))
    if len(features) == 0 or radius_px <= 0:
        return features
    keep = np.flatnonzero(~near_pixels(pts, features.pixels, radius_px))
    return Features(
        features.pixels[keep],
        features.descriptors[keep],
        [features.keypoints[i] for i in keep],
        features.size,
    )


def match_frame(
    rig: CameraRig,
    images: list[np.ndarray],
    edges: np.ndarray,
    config: MatchingConfig | None = None,
    *,
    skip: np.ndarray | None = None,
    skip_px: float = 0.0,
    boxes: list[np.ndarray] | None = None,
) -> MultiViewTracks:
    """Dense multi-view correspondences of one time instant.

    Parameters
    ----------
    rig : CameraRig
        C cameras.
    images : list of C (H_c, W_c, 3) uint8 RGB or (H_c, W_c) grey ndarrays
    edges : (E, 2) int ndarray
        Camera pairs to match (the connectivity graph's edges).
    config : MatchingConfig, optional
    skip : (C, Q, 2) float ndarray, optional
        Pixels (distorted, NaN where absent) around which no feature is matched: the
        tracker's live trajectories (``[reconstruct] match_skip_px``). The features are
        detected on the whole image as without it, and those within ``skip_px`` of one of
        these pixels of their camera are left out (:func:`without_near`).
    skip_px : float
        See ``skip``.
    boxes : list of C (B_c, 4) int ndarrays, optional
        Detect features only inside these boxes of each camera (:func:`detect_features`;
        :func:`moving_boxes`); a camera with none has no features. Default: whole images.

    Returns
    -------
    MultiViewTracks
    """
    cfg = config or MatchingConfig()
    if len(images) != len(rig):
        raise ValidationError(f"images: expected {len(rig)} images, got {len(images)}")
    edges = check_array("edges", edges, (None, 2), dtype=np.int64)
    if edges.size and (edges.min() < 0 or edges.max() >= len(rig)):
        raise ValidationError(f"edges: camera indices must be in [0, {len(rig)})")
    for c, img in enumerate(images):
        w, h = rig.sizes[c]
        if np.asarray(img).shape[:2] != (h, w):
            raise ValidationError(
                f"image of camera {rig.names[c]!r} is {np.asarray(img).shape[1::-1]}, "
                f"the rig says {w}x{h}"
            )
    if boxes is not None and len(boxes) != len(rig):
        raise ValidationError(f"boxes: expected {len(rig)} lists of boxes, got {len(boxes)}")
    feats = [
        detect_features(img, cfg, None if boxes is None else boxes[c])
        for c, img in enumerate(images)
    ]
    if skip is not None:
        skip = check_array("skip", skip, (len(rig), None, 2))
        feats = [without_near(f, skip[c], skip_px) for c, f in enumerate(feats)]
    matches = match_pairs(rig, feats, edges, cfg)
    tracks = build_tracks(len(rig), feats, edges, matches)
    logger.info(
        "matched %d pairs: %d features, %d matches, %d tracks (%d ambiguous)",
        len(edges),
        sum(len(f) for f in feats),
        sum(len(m) for m in matches),
        tracks.num_tracks,
        int(tracks.ambiguous.sum()),
    )
    return tracks
