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
from dataclasses import dataclass

import numpy as np

from ..camera import CameraRig, undistort_normalized
from ..errors import ValidationError, check_array

__all__ = [
    "MatchingConfig",
    "Features",
    "MultiViewTracks",
    "detect_features",
    "match_pair",
    "epipolar_distances",
    "build_tracks",
    "resolve_ambiguous",
    "match_frame",
]

logger = logging.getLogger(__name__)


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
    gms_threshold : float
        GMS ``thresholdFactor``: the higher, the fewer matches survive.
    gms_rotation, gms_scale : bool
        Let GMS search over rotations / scales (off for rigs of upright cameras).
    cross_check : bool
        Keep only mutual nearest neighbours (before GMS; in both directions of guided matching).
    epipolar_px : float
        Maximum distance (pixels, in undistorted coordinates, the larger of the two directions)
        between a keypoint and the epipolar line of its match.
    guided : bool
        Epipolar-guided matching: each keypoint is compared only with the keypoints of the other
        image within ``epipolar_px`` of its epipolar line (known calibration), with Lowe's ratio
        test. Far more matches across wide baselines than unguided nearest neighbours.
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
    gms_threshold: float = 6.0
    gms_rotation: bool = False
    gms_scale: bool = False
    cross_check: bool = False
    epipolar_px: float = 2.5
    guided: bool = False
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
        if self.epipolar_px <= 0 or self.gms_threshold <= 0:
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


def detect_features(image: np.ndarray, config: MatchingConfig | None = None) -> Features:
    """ORB features spread over a grid.

    Parameters
    ----------
    image : (H, W, 3) uint8 RGB or (H, W) uint8 grey ndarray
    config : MatchingConfig, optional

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
    orb = cv2.ORB_create(
        nfeatures=int(cfg.num_features * cfg.oversample),
        scaleFactor=1.2,
        nlevels=cfg.pyramid_levels,
        edgeThreshold=cfg.patch_size,
        patchSize=cfg.patch_size,
        fastThreshold=cfg.fast_threshold,
    )
    kps = orb.detect(grey, None)
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
    xa = _normalized(rig, cam_a, pa)  # (N, 2)
    xb = _normalized(rig, cam_b, pb)
    Ra, Rb = rig.R[cam_a], rig.R[cam_b]
    R = Rb @ Ra.T
    t = Rb @ (rig.C[cam_a] - rig.C[cam_b])
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    E = tx @ R  # x_b^T E x_a = 0
    ha = np.concatenate([xa, np.ones((len(xa), 1))], axis=1)  # (N, 3)
    hb = np.concatenate([xb, np.ones((len(xb), 1))], axis=1)
    lb = ha @ E.T  # (N, 3) lines in image b
    la = hb @ E  # (N, 3) lines in image a
    alg = np.sum(hb * lb, axis=1)  # (N,)
    with np.errstate(divide="ignore", invalid="ignore"):
        db = np.abs(alg) / np.hypot(lb[:, 0], lb[:, 1]) * rig.K[cam_b, 0, 0]
        da = np.abs(alg) / np.hypot(la[:, 0], la[:, 1]) * rig.K[cam_a, 0, 0]
    return np.fmax(da, db)


def _normalized(rig: CameraRig, cam: int, pixels: np.ndarray) -> np.ndarray:
    K = rig.K[cam]
    y = (pixels[:, 1] - K[1, 2]) / K[1, 1]
    x = (pixels[:, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return undistort_normalized(np.stack([x, y], axis=-1), rig.dist[cam])


def match_pair(
    rig: CameraRig,
    cam_a: int,
    cam_b: int,
    features_a: Features,
    features_b: Features,
    config: MatchingConfig | None = None,
) -> np.ndarray:
    """Brute-force Hamming matches filtered by GMS and the epipolar constraint.

    Parameters
    ----------
    rig : CameraRig
    cam_a, cam_b : int
        Camera indices of the two images.
    features_a, features_b : Features
    config : MatchingConfig, optional

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
        raw = _guided_matches(rig, cam_a, cam_b, features_a, features_b, cfg)
        if cfg.cross_check and raw:  # keep mutual nearest neighbours only
            back = _guided_matches(rig, cam_b, cam_a, features_b, features_a, cfg)
            fwd = np.array([(m.queryIdx, m.trainIdx) for m in raw], dtype=np.int64)
            bwd = np.array([(m.trainIdx, m.queryIdx) for m in back], dtype=np.int64).reshape(-1, 2)
            nb = len(features_b)
            mutual = np.isin(fwd[:, 0] * nb + fwd[:, 1], bwd[:, 0] * nb + bwd[:, 1])
            raw = [m for m, ok in zip(raw, mutual.tolist()) if ok]
    else:
        raw = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=cfg.cross_check).match(
            features_a.descriptors, features_b.descriptors
        )
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
            thresholdFactor=cfg.gms_threshold,
        )
    if not good:
        return np.zeros((0, 2), np.int64)
    pairs = np.array([(m.queryIdx, m.trainIdx) for m in good], dtype=np.int64)  # (Q, 2)
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


def _guided_matches(
    rig: CameraRig,
    cam_a: int,
    cam_b: int,
    features_a: Features,
    features_b: Features,
    cfg: MatchingConfig,
    chunk: int = 2048,
) -> list:
    """Nearest neighbours within the epipolar band, with the ratio test (cv2.DMatch list)."""
    import cv2

    xa = _normalized(rig, cam_a, features_a.pixels.astype(np.float64))
    xb = _normalized(rig, cam_b, features_b.pixels.astype(np.float64))
    R = rig.R[cam_b] @ rig.R[cam_a].T
    t = rig.R[cam_b] @ (rig.C[cam_a] - rig.C[cam_b])
    E = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]]) @ R
    ha = np.concatenate([xa, np.ones((len(xa), 1))], axis=1)  # (Na, 3)
    hb = np.concatenate([xb, np.ones((len(xb), 1))], axis=1).T  # (3, Nb)
    tol = cfg.epipolar_px / rig.K[cam_b, 0, 0]  # band half-width, normalised units of b
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    out = []
    for s in range(0, len(ha), chunk):  # bounded (chunk, Nb) band masks
        lines = ha[s : s + chunk] @ E.T  # (n, 3) epipolar lines in b
        norm = np.hypot(lines[:, 0], lines[:, 1])[:, None]
        mask = (np.abs(lines @ hb) <= tol * norm).astype(np.uint8)  # (n, Nb)
        knn = bf.knnMatch(
            features_a.descriptors[s : s + chunk], features_b.descriptors, k=2, mask=mask
        )
        best = np.array(
            [
                (c[0].queryIdx, c[0].trainIdx, c[0].distance, c[1].distance if len(c) > 1 else 1e9)
                for c in knn
                if c
            ],
            dtype=np.float64,
        ).reshape(-1, 4)  # (n', 4): query, train, best, second-best distance
        ok = best[:, 2] < cfg.ratio * best[:, 3]
        out += [cv2.DMatch(int(q) + s, int(tr), float(d)) for q, tr, d in best[ok, :3].tolist()]
    return out


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
    err = np.linalg.norm(proj.pixels[cam, col] - tracks.node_pixels[amb_nodes], axis=1)  # (V',)
    err = np.where(np.isfinite(err), err, np.inf)
    order = np.lexsort((err, cam, trk))
    key = trk[order] * len(rig) + cam[order]
    first = np.concatenate([[True], key[1:] != key[:-1]])
    best = order[first]
    ok = np.isfinite(err[best])
    obs[cam[best][ok], trk[best][ok]] = tracks.node_pixels[amb_nodes[best[ok]]]
    return obs


def match_frame(
    rig: CameraRig,
    images: list[np.ndarray],
    edges: np.ndarray,
    config: MatchingConfig | None = None,
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
    feats = [detect_features(img, cfg) for img in images]
    matches = [match_pair(rig, int(a), int(b), feats[a], feats[b], cfg) for a, b in edges]
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
