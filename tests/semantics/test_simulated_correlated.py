"""Tests of the simulated recogniser's correlated noise model (issue 19) and of the independent
model it replaced as the default (pointtraj.semantics.recognizers.simulated)."""

from __future__ import annotations

import dataclasses
import logging
import zlib

import numpy as np
import pytest
from helpers import labelmaps

from pointtraj.errors import ValidationError
from pointtraj.labelset import LabelSet
from pointtraj.semantics.recognizers import ImageContext, make_recognizer
from pointtraj.semantics.recognizers.simulated import (
    INDEPENDENT_PRESETS,
    NOISE_PRESETS,
    SimulatedNoise,
    SimulatedRecognizer,
    _class_distance,
    lateral_sides,
    noise_preset,
    simulate_confidences,
    view_cosines,
)

LABELS = LabelSet.default()
SIDE = lateral_sides(LABELS.names)
#: The correlated model with every error off: 1-pixel cells, no blur, peak 1, lengths in the
#: test images' own pixels.
CLEAN = dataclasses.replace(
    NOISE_PRESETS["none"],
    downsample=1,
    p_flip_front=0.0,
    p_flip_side=0.0,
    p_flip_back=0.0,
    length_reference_px=0.0,
)


def figure_map(H=96, W=128):
    """A torso, both forearms and hands (the figure of test_simulated.py), and a ball."""
    return labelmaps.figure_map(LABELS, H, W)


def mirrored_share(L2D, lab):
    """Share of the lateral ground-truth pixels whose argmax has the other side."""
    arg = L2D.argmax(axis=2)
    gt, rep = SIDE[np.maximum(lab, 0)] * (lab >= 0), SIDE[arg]
    both = (gt != 0) & (rep != 0)
    return float(np.mean(gt[both] != rep[both]))


# -- the independent model is unchanged --------------------------------------------------------
#: simulate_confidences(figure_map(), LABELS.names, LABELS.kinds, <independent preset>,
#: camera=..., frame=..., seed=7) computed with main's implementation before issue 19 (commit
#: 7129715): per-class sums (rounded to 1e-3) and the argmax of every cell (hex, row-major).
REFERENCE = {
    ("high", "c01", 3): (
        [
            11.827,
            32.759,
            12.615,
            12.859,
            19.996,
            19.639,
            16.31,
            16.483,
            12.137,
            12.318,
            12.077,
            12.284,
            17.616,
            11.292,
            28.971,
            13.114,
        ],
        "f9ca616ae8fbc039c9f973411116a56c3cc44411ccc5247f6ac4441111555f5511c44111115555d8a2c444"
        "111155551f43644111115556fc2654411111177bc882c66611117eeeeec9f66601177eeeee5e5b66d1c78e"
        "eeeef89fc6b7781eeeee",
    ),
    ("default", "c02", 40): (
        [
            7.107,
            21.189,
            7.545,
            15.411,
            15.872,
            7.545,
            16.256,
            7.463,
            7.687,
            6.901,
            7.609,
            7.88,
            7.789,
            6.667,
            18.808,
            6.782,
        ],
        "2657f5057012a186855b4441133336a34244441111333936f5444411113333468f44441111333bf4b07444"
        "1111333eb496444411113333214b66461111663bbc606666111166eeeeccd666611666eeee2df666e7d666"
        "eeee7122941bf831eeee",
    ),
    ("low", "c03", 17): (
        [
            3.363,
            21.47,
            3.318,
            3.348,
            15.097,
            13.396,
            8.274,
            8.477,
            3.068,
            3.063,
            3.104,
            3.161,
            3.023,
            3.217,
            18.221,
            4.645,
        ],
        "36dd3e31180b0fb44244441111ff5fa2b544441111ff559c434444111155555a044444111155555aa44444"
        "111155558a44444411115555750044441111777545856666111177eeee926666611777eeeeea6666667777"
        "eeee8a2860e2d777eeee",
    ),
}


@pytest.mark.parametrize("preset, camera, frame", list(REFERENCE))
def test_independent_model_output_is_unchanged(preset, camera, frame):
    """Regression: the independent model (the default before issue 19) gives, for a fixed seed,
    the same output as main's implementation did."""
    sums, arg = REFERENCE[(preset, camera, frame)]
    for noise in (INDEPENDENT_PRESETS[preset], noise_preset(preset, "independent")):
        out = simulate_confidences(
            figure_map(), LABELS.names, LABELS.kinds, noise, camera=camera, frame=frame, seed=7
        )
        assert out.shape == (12, 16, 16)
        np.testing.assert_allclose(out.sum(axis=(0, 1)), sums, atol=2e-3)
        assert "".join(f"{a:x}" for a in out.argmax(axis=2).ravel()) == arg
    rec = SimulatedRecognizer(LABELS.names, LABELS.kinds, noise=preset, model="independent")
    assert rec.noise == INDEPENDENT_PRESETS[preset]


#: simulate_confidences(<figure_map(192, 256)>, ..., <correlated preset, lengths in pixels,
#: p_flip_front 0.5>, camera=..., frame=..., seed=3, <two figures by column>) computed with
#: main's implementation before the faster soft boundaries (commit b2ba36c): per-class sums
#: (rounded to 1e-3) and the CRC-32 of the argmax of every cell (int16, little-endian).
REFERENCE_CORRELATED = {
    ("default", "c01", 3): (
        [492.549, 847.685, 613.134, 491.79, 642.419, 665.304, 600.38, 579.871]
        + [617.1, 493.181, 490.77, 611.362, 491.588, 489.861, 575.377, 534.279],
        2195433199,
    ),
    ("high", "c02", 40): (
        [798.827, 1198.022, 780.84, 792.206, 983.066, 790.014, 953.254, 870.607]
        + [801.119, 818.148, 783.664, 777.447, 781.143, 785.905, 786.403, 787.62],
        3691462920,
    ),
    ("high", "c05", 7): (
        [792.257, 790.766, 775.787, 782.058, 1080.082, 945.661, 889.729, 861.471]
        + [784.744, 783.479, 783.251, 778.802, 945.102, 780.527, 929.893, 784.141],
        5129697,
    ),
}


@pytest.mark.parametrize("preset, camera, frame", list(REFERENCE_CORRELATED))
def test_correlated_model_output_is_unchanged(preset, camera, frame):
    """Regression: shifted and soft boundaries computed part by part in each part's box (and
    the other speed-ups) give the output of the whole-crop implementation, with boundary
    shifts, soft boundaries, figure flips by instance, a ball and false positives all on."""
    lab = labelmaps.figure_map(LABELS, 192, 256)
    inst = np.where(lab >= 0, 0, -1)
    inst[:, 128:] = np.where(lab[:, 128:] >= 0, 1, -1)
    noise = dataclasses.replace(NOISE_PRESETS[preset], length_reference_px=0.0, p_flip_front=0.5)
    out = simulate_confidences(
        lab,
        LABELS.names,
        LABELS.kinds,
        noise,
        camera=camera,
        frame=frame,
        seed=3,
        instances=inst,
        facing={0: 1.0, 1: 0.9},
    )
    sums, crc = REFERENCE_CORRELATED[(preset, camera, frame)]
    assert out.shape == (96, 128, 16)
    np.testing.assert_allclose(out.sum(axis=(0, 1)), sums, atol=2e-3)
    assert zlib.crc32(out.argmax(axis=2).astype("<i2").tobytes()) == crc


def test_part_distances_in_a_box_are_the_whole_maps():
    """_class_distance: inside the part's widened box, the whole map's distance transform (to
    float rounding); outside it, at least the reach. The boundary shift and the soft
    boundaries rely on both."""
    import cv2

    rng = np.random.default_rng(0)
    for _ in range(60):
        coarse = rng.integers(-1, 6, rng.integers(2, 8, 2)).astype(np.float32)
        size = (int(rng.integers(20, 160)), int(rng.integers(20, 160)))
        lab = cv2.resize(coarse, size, interpolation=cv2.INTER_NEAREST).astype(np.int64)
        for k in np.unique(lab):
            whole = cv2.distanceTransform((lab != k).astype(np.uint8), cv2.DIST_L2, 5)
            reach = int(rng.integers(1, 30))
            (rows, cols), d = _class_distance(lab, int(k), reach)
            np.testing.assert_allclose(d, whole[rows, cols], rtol=1e-6)
            outside = np.ones(lab.shape, bool)
            outside[rows, cols] = False
            assert (whole[outside] >= reach).all()
            assert (lab[outside] != k).all()


def test_blur_treats_channels_one_by_one():
    """The body parts' blur runs on every class channel at once (objects included, then
    zeroed): OpenCV's Gaussian blur must give each channel what it gives it alone."""
    import cv2

    rng = np.random.default_rng(1)
    frac = rng.random((40, 56, 16)).astype(np.float32)
    frac[frac < 0.6] = 0.0
    for sigma in (1.0, 1.5):
        every = cv2.GaussianBlur(frac, (0, 0), sigma, borderType=cv2.BORDER_REPLICATE)
        for k in (0, 7, 15):
            alone = cv2.GaussianBlur(
                np.ascontiguousarray(frac[:, :, k]), (0, 0), sigma, borderType=cv2.BORDER_REPLICATE
            )
            np.testing.assert_array_equal(every[:, :, k], alone)


def test_presets_and_models():
    assert SimulatedRecognizer(LABELS.names).noise == NOISE_PRESETS["default"]
    assert NOISE_PRESETS["default"].model == "correlated" and NOISE_PRESETS["default"].correlated
    assert all(p.model == "independent" and not p.correlated for p in INDEPENDENT_PRESETS.values())
    low = make_recognizer("simulated", LABELS, noise="low", model="independent", p_miss=0.5)
    assert low.noise == dataclasses.replace(INDEPENDENT_PRESETS["low"], p_miss=0.5)
    # the presets of the correlated model are ordered by their error rates
    rates = [NOISE_PRESETS[n] for n in ("none", "low", "default", "high")]
    for a, b in zip(rates, rates[1:]):
        assert a.p_flip_front <= b.p_flip_front and a.boundary_px <= b.boundary_px


def test_bad_configurations_are_clear_errors():
    with pytest.raises(ValidationError, match="model: unknown noise model 'magic'"):
        SimulatedNoise(model="magic")
    with pytest.raises(ValidationError, match="model: unknown noise model 'magic'"):
        SimulatedRecognizer(LABELS.names, model="magic")
    with pytest.raises(ValidationError, match="boundary_px: a parameter of the correlated"):
        SimulatedRecognizer(LABELS.names, model="independent", boundary_px=3.0)
    with pytest.raises(ValidationError, match="p_flip_back: must be in"):
        SimulatedRecognizer(LABELS.names, p_flip_back=1.5)
    with pytest.raises(ValidationError, match="softness_px: must be >= 0"):
        SimulatedNoise(model="correlated", softness_px=-1.0)
    with pytest.raises(ValidationError, match="unknown preset 'loud'"):
        noise_preset("loud", "independent")
    with pytest.raises(ValidationError, match="unknown option 'p_flipback'"):
        SimulatedRecognizer(LABELS.names, p_flipback=0.3)
    with pytest.raises(ValidationError, match="instances: expected an"):
        simulate_confidences(figure_map(), LABELS.names, instances=np.zeros((3, 3), np.int16))


# -- viewing-direction-dependent flips ---------------------------------------------------------
def test_view_cosines_front_side_back():
    from pointtraj.camera import Camera, CameraRig

    rig = CameraRig(
        [
            Camera.look_at(n, c, (0, 0, 1), (64, 48), 50.0)
            for n, c in (("front", (3, 0, 1.5)), ("left", (0, 3, 1)), ("back", (-3, 0.1, 2)))
        ]
    )
    cos = view_cosines(np.array([[1.0, 0, 0.3]]), np.array([[0.0, 0, 1]]), rig, np.array([0, 0, 1]))
    assert cos.shape == (1, 3)
    np.testing.assert_allclose(cos[0], [1.0, 0.0, -np.cos(np.arctan(0.1 / 3))], atol=1e-9)
    assert np.isnan(view_cosines(np.array([0, 0, 1.0]), np.zeros(3), rig, np.array([0, 0, 1])))[0]


def test_back_views_flip_more_than_front_views():
    """Over 300 cameras, a figure seen from behind is mirrored at p_flip_back, from the front at
    p_flip_front, from the side at p_flip_side; a whole flip mirrors every lateral pixel."""
    lab = figure_map()
    noise = dataclasses.replace(CLEAN, p_flip_front=0.1, p_flip_side=0.4, p_flip_back=0.8)
    rates = {}
    for name, cos in (("front", 1.0), ("side", 0.0), ("back", -1.0)):
        shares = [
            mirrored_share(
                simulate_confidences(
                    lab, LABELS.names, LABELS.kinds, noise, camera=f"c{i}", facing={0: cos}
                ),
                lab,
            )
            for i in range(300)
        ]
        assert set(np.round(shares, 6)) <= {0.0, 1.0}  # the whole figure, or nothing
        rates[name] = np.mean(shares)
    assert abs(rates["front"] - 0.1) < 0.05
    assert abs(rates["side"] - 0.4) < 0.07
    assert abs(rates["back"] - 0.8) < 0.06
    assert noise.flip_probability(np.array([0.5, -0.5, np.nan])) == pytest.approx([0.25, 0.6, 0.4])


def test_coupled_flips_are_shared_by_the_views_of_a_frame_block():
    """With flip_coupling 1 all back views of a figure flip together (one draw per figure and
    block); with 0 each view draws its own."""
    lab = figure_map()
    coupled = dataclasses.replace(CLEAN, p_flip_back=0.5, flip_coupling=1.0, hold_frames=10)
    own = dataclasses.replace(coupled, flip_coupling=0.0)
    for noise, together in ((coupled, True), (own, False)):
        agree = []
        for block in range(40):
            shares = [
                mirrored_share(
                    simulate_confidences(
                        lab,
                        LABELS.names,
                        LABELS.kinds,
                        noise,
                        camera=f"cam{c}",
                        frame=10 * block,
                        facing={0: -1.0},
                    ),
                    lab,
                )
                for c in range(4)
            ]
            agree.append(len(set(shares)) == 1)
        assert all(agree) if together else np.mean(agree) < 0.5


def test_figures_flip_one_by_one_through_the_instance_map():
    """Two figures in one image: only the one seen from behind is mirrored."""
    lab = figure_map()
    inst = np.full(lab.shape, -1, np.int16)
    inst[:, :64][lab[:, :64] >= 0] = 3  # left half: figure 3 (its left forearm and hand)
    inst[:, 64:][lab[:, 64:] >= 0] = 5  # right half: figure 5 (and the ball)
    noise = dataclasses.replace(CLEAN, p_flip_back=1.0)
    L = simulate_confidences(
        lab, LABELS.names, LABELS.kinds, noise, instances=inst, facing={3: 1.0, 5: -1.0}
    )
    arg = L.argmax(axis=2)
    assert (arg[lab == LABELS.index("left_hand")] == LABELS.index("left_hand")).all()
    assert (arg[lab == LABELS.index("right_hand")] == LABELS.index("left_hand")).all()
    assert (arg[lab == LABELS.index("right_forearm")] == LABELS.index("left_forearm")).all()
    assert (arg[lab == LABELS.index("torso")] == LABELS.index("torso")).all()


# -- part boundaries ---------------------------------------------------------------------------
def two_parts(H=64, W=96):
    """Left forearm (columns < 48) beside the left hand (columns >= 48) on a background frame."""
    lab = np.full((H, W), -1, np.int16)
    lab[8:56, 8:48] = LABELS.index("left_forearm")
    lab[8:56, 48:88] = LABELS.index("left_hand")
    return lab


def test_boundary_confusions_stay_in_a_band_along_the_boundary():
    """Confusions between neighbouring parts lie within boundary_px of their boundary, on both
    sides along its length, and never far from it."""
    lab = two_parts()
    noise = dataclasses.replace(CLEAN, boundary_px=6.0, boundary_scale_px=12.0)
    moved_cols, moved_any = [], 0
    for i in range(20):
        arg = simulate_confidences(lab, LABELS.names, noise=noise, camera=f"c{i}").argmax(2)
        changed = (arg != lab) & (lab >= 0)
        moved_any += changed.any()
        moved_cols.extend(np.nonzero(changed)[1].tolist())
        assert ((arg == LABELS.index("left_hand")) | (arg == LABELS.index("left_forearm")))[
            lab >= 0
        ].all()
    cols = np.array(moved_cols)
    assert moved_any >= 18
    assert cols.min() >= 48 - 6 and cols.max() < 48 + 6  # the band: 6 px either side
    assert (cols < 48).any() and (cols >= 48).any()  # either part encroaches somewhere
    # no confusion at all without boundary_px
    clean = simulate_confidences(lab, LABELS.names, noise=CLEAN).argmax(2)
    np.testing.assert_array_equal(clean[lab >= 0], lab[lab >= 0])


def test_soft_boundaries_fall_off_with_the_distance_to_the_neighbour():
    """With softness s, the neighbour's confidence at distance d from its part is about
    exp(-(d / s)^2); a part's own pixels keep the peak; background stays 0."""
    lab = two_parts()
    L = simulate_confidences(lab, LABELS.names, noise=dataclasses.replace(CLEAN, softness_px=4.0))
    hand = L[30, :, LABELS.index("left_hand")]
    assert hand[48:88].min() == pytest.approx(1.0)
    for d in (1, 2, 4, 6):  # the forearm pixel d columns left of the hand's first column
        assert hand[48 - d] == pytest.approx(np.exp(-((d / 4.0) ** 2)), abs=0.03)
    assert L[lab < 0].max() == 0.0


def test_lengths_scale_with_the_image():
    """The same figure at twice the resolution gets a soft band twice as wide (in pixels), so
    the same share of the figure; with length_reference_px = 0 the band stays in pixels."""
    small = two_parts(64, 96)
    big = np.repeat(np.repeat(small, 2, axis=0), 2, axis=1)
    hand = LABELS.index("left_hand")

    def band(lab, ref):
        noise = dataclasses.replace(CLEAN, softness_px=4.0, length_reference_px=ref)
        row = simulate_confidences(lab, LABELS.names, noise=noise)[lab.shape[0] // 2, :, hand]
        return int(((row > 0.5) & (row < 0.999)).sum())

    assert band(small, 96) >= 2 and band(big, 96) == 2 * band(small, 96)
    assert band(big, 0) == band(small, 0)


# -- the recogniser on a rendered capture ------------------------------------------------------
@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    from pointtraj.synth import render_capture

    out = tmp_path_factory.mktemp("simcorr") / "cap"
    render_capture(out, preset="tiny4", scene="dribble", frames=2, points_per_part=200)
    return out


def test_facing_comes_from_the_ground_truth_poses(capture):
    """The recogniser's viewing directions are those of the figure's torso against the rig."""
    from pointtraj.rigio import load_rig
    from pointtraj.semantics.recognizers.simulated import _view_facing
    from pointtraj.synth.groundtruth import segment_ground_truth

    seg = segment_ground_truth(capture)
    rig = load_rig(capture / "rig.toml")
    torso = int(np.flatnonzero(seg.part_label == LABELS.index("torso"))[0])
    pose = seg.part_poses[torso, 1]
    for c, cam in enumerate(rig.names):
        cos = _view_facing(str(capture), LABELS.index("torso"), cam, 1)
        to_cam = rig[c].C - pose[:3, 3]
        expected = (
            (pose[:2, 0] @ to_cam[:2]) / np.linalg.norm(pose[:2, 0]) / np.linalg.norm(to_cam[:2])
        )
        assert cos == {0: pytest.approx(expected)}


def test_recognizer_flips_by_the_captures_viewing_directions(capture):
    """Views from behind (cos < 0) are mirrored when p_flip_back = p_flip_side = 1, views from
    the front (cos > 0) never when p_flip_front = p_flip_side = 0."""
    from pointtraj.semantics.recognizers.simulated import _view_facing
    from pointtraj.synth.groundtruth import load_label_map

    back = SimulatedRecognizer(LABELS.names, LABELS.kinds, noise=CLEAN, p_flip_back=1.0)
    back_side = SimulatedRecognizer(
        LABELS.names, LABELS.kinds, noise=CLEAN, p_flip_back=1.0, p_flip_side=1.0
    )
    seen = set()
    for cam in ("cam00", "cam01", "cam02", "cam03"):
        cos = _view_facing(str(capture), LABELS.index("torso"), cam, 0)[0]
        if abs(cos) < 0.1:
            continue
        lab = load_label_map(capture, cam, 0)
        ctx = ImageContext(cam, 0, str(capture))
        if cos < 0:
            assert mirrored_share(back_side.recognize(None, ctx), lab) == 1.0, (cam, cos)
        else:
            assert mirrored_share(back.recognize(None, ctx), lab) == 0.0, (cam, cos)
        seen.add(cos < 0)
    assert seen == {True, False}


def test_occluders_class_is_reported_at_an_occluded_points_projection(capture):
    """The label maps are rendered front surfaces: at the projection of a ground-truth point
    hidden in a view, the simulator reports what hides it (another part, the ball), not the
    point's own class."""
    from pointtraj.rigio import load_rig
    from pointtraj.synth import load_ground_truth
    from pointtraj.synth.groundtruth import load_label_map

    gt = load_ground_truth(capture)
    rig = load_rig(capture / "rig.toml")
    labels = LabelSet.load(capture / "labels.toml")
    rec = SimulatedRecognizer.from_labelset(labels, noise=CLEAN)
    front = by_other = reported_own = total = 0
    for t in range(gt.num_frames):
        proj = rig.project(gt.xyz[:, t])
        for c, cam in enumerate(gt.camera_names):
            hidden = ~gt.visible[:, t, c] & proj.in_image[c]
            px = np.rint(proj.pixels[c, hidden]).astype(int)
            seen = load_label_map(capture, cam, t)[px[:, 1], px[:, 0]]  # the front surface
            L = rec.recognize(None, ImageContext(cam, t, str(capture)))
            arg = L[px[:, 1], px[:, 0]].argmax(axis=1)
            hit = seen >= 0
            total += hit.sum()
            front += np.sum(hit & (arg == seen))
            other = hit & (seen != gt.label[hidden])  # hidden behind another class
            by_other += other.sum()
            reported_own += np.sum(other & (arg == gt.label[hidden]))
    assert total > 5000 and by_other > 500
    assert front / total > 0.99
    assert reported_own == 0


def test_captures_without_ground_truth_poses_fall_back_with_a_message(tmp_path, caplog):
    from pointtraj.synth import groundtruth

    groundtruth.save_label_map(tmp_path, "cam03", 0, figure_map())
    rec = SimulatedRecognizer(LABELS.names, LABELS.kinds, noise=CLEAN, p_flip_side=1.0)
    with caplog.at_level(logging.WARNING):
        L = rec.recognize(None, ImageContext("cam03", 0, capture=str(tmp_path)))
    assert "no figure facing directions" in caplog.text and "p_flip_side" in caplog.text
    assert mirrored_share(L, figure_map()) == 1.0  # unknown direction: the side rate
