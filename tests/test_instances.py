"""People as instances (pointtraj.instances): rigid groups, person-mask splits and merges."""

from __future__ import annotations

import numpy as np
import pytest

from pointtraj.errors import ValidationError
from pointtraj.instances import (
    InstanceConfig,
    assign_instances,
    instance_accuracy,
    match_instances,
    person_classes,
)

CFG = InstanceConfig(min_trajectories=2, min_shared=3)


def _chain(nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edges joining consecutive nodes (a connected rigid group)."""
    return nodes[:-1], nodes[1:]


def _votes(tracks: np.ndarray, images: np.ndarray, person: int | np.ndarray) -> np.ndarray:
    """Every track in every image, in the given person's mask: (V, 3) rows."""
    t, i = np.meshgrid(tracks, images, indexing="ij")
    p = np.broadcast_to(np.asarray(person), t.shape) if np.ndim(person) == 0 else person
    return np.stack([t.ravel(), i.ravel(), np.broadcast_to(p, t.shape).ravel()], axis=1)


def test_two_rigid_groups_ordered_by_size():
    labels = np.zeros(9, np.int64)
    r1, c1 = _chain(np.arange(0, 3))  # small group: 0, 1, 2
    r2, c2 = _chain(np.arange(3, 9))  # large group: 3..8
    row, col = np.concatenate([r1, r2]), np.concatenate([c1, c2])
    out = assign_instances(labels, np.array([0]), row, col, np.ones(len(row)), config=CFG)
    assert out.dtype == np.int64 and out.shape == (9,)
    assert out.tolist() == [1, 1, 1, 0, 0, 0, 0, 0, 0]


def test_chance_edge_between_two_people_is_cut_by_the_masks():
    """Two people joined by one heavy edge (they touch): the masks disagree, the edge is cut."""
    labels = np.zeros(10, np.int64)
    a, b = np.arange(0, 5), np.arange(5, 10)
    r1, c1 = _chain(a)
    r2, c2 = _chain(b)
    row = np.concatenate([r1, r2, [4]])
    col = np.concatenate([c1, c2, [5]])
    w = np.ones(len(row))
    joined = assign_instances(labels, np.array([0]), row, col, w, config=CFG)
    assert len(set(joined.tolist())) == 1  # the graph alone makes one person
    images = np.arange(6)
    # image-local ids differ between images: person A is id 0 in even images, 1 in odd ones
    votes = np.concatenate([_votes(a, images, images % 2), _votes(b, images, 1 - images % 2)])
    out = assign_instances(labels, np.array([0]), row, col, w, votes, CFG)
    assert len(set(out[a].tolist())) == 1 and len(set(out[b].tolist())) == 1
    assert out[0] != out[5] and set(out.tolist()) == {0, 1}


def test_pieces_of_one_person_are_merged_by_the_masks():
    """A hand with no rigid partner is joined to its body because the masks agree."""
    labels = np.zeros(12, np.int64)
    body, hand, other = np.arange(0, 6), np.arange(6, 8), np.arange(8, 12)
    edges = [_chain(body), _chain(hand), _chain(other)]
    row = np.concatenate([e[0] for e in edges])
    col = np.concatenate([e[1] for e in edges])
    w = np.ones(len(row))
    images = np.arange(5)
    votes = np.concatenate(
        [_votes(body, images, 0), _votes(hand, images, 0), _votes(other, images, 1)]
    )
    without = assign_instances(labels, np.array([0]), row, col, w, config=CFG)
    assert len(set(without.tolist())) == 3
    out = assign_instances(labels, np.array([0]), row, col, w, votes, CFG)
    assert out.tolist() == [0] * 8 + [1] * 4
    assert instance_accuracy(out, np.array([5] * 8 + [7] * 4)) == 1.0


def test_merge_refused_between_groups_that_the_masks_tell_apart():
    """A piece agreeing with two people in different images does not join them into one."""
    labels = np.zeros(12, np.int64)
    a, b, piece = np.arange(0, 5), np.arange(5, 10), np.arange(10, 12)
    edges = [_chain(a), _chain(b), _chain(piece)]
    row = np.concatenate([e[0] for e in edges])
    col = np.concatenate([e[1] for e in edges])
    # a and b are seen together in images 0-5, always in different masks; the piece shares
    # images 0-4 with a (same mask) and images 6-10 with b (same mask).
    votes = np.concatenate(
        [
            _votes(a, np.arange(0, 6), 0),
            _votes(b, np.arange(0, 6), 1),
            _votes(b, np.arange(6, 11), 0),
            _votes(piece, np.arange(0, 5), 0),
            _votes(piece, np.arange(6, 11), 0),
        ]
    )
    out = assign_instances(labels, np.array([0]), row, col, np.ones(len(row)), votes, CFG)
    assert out[a[0]] != out[b[0]]
    assert out[piece[0]] in (out[a[0]], out[b[0]])


def test_other_classes_light_edges_and_small_groups_get_no_person():
    labels = np.array([0, 0, 0, 1, 1, -1, 0, 0])
    row = np.array([0, 1, 3, 4, 6])
    col = np.array([1, 2, 4, 5, 7])
    w = np.array([1.0, 1.0, 1.0, 1.0, 0.01])  # the last is below min_weight
    out = assign_instances(
        labels, np.array([0]), row, col, w, config=InstanceConfig(min_trajectories=3)
    )
    assert out.tolist() == [0, 0, 0, -1, -1, -1, -1, -1]
    empty = assign_instances(np.zeros(0, np.int64), np.array([0]), [], [], [])
    assert empty.shape == (0,)


def test_bad_input_is_refused():
    with pytest.raises(ValidationError, match="row, col"):
        assign_instances(np.zeros(3, np.int64), np.array([0]), [0], [5], [1.0])
    with pytest.raises(ValidationError, match="weight"):
        assign_instances(np.zeros(3, np.int64), np.array([0]), [0], [1], [1.0, 2.0])
    with pytest.raises(ValidationError, match="person_votes"):
        assign_instances(np.zeros(3, np.int64), np.array([0]), [], [], [], np.zeros((2, 2)))
    with pytest.raises(ValidationError, match="person_votes"):
        assign_instances(np.zeros(3, np.int64), np.array([0]), [], [], [], [[7, 0, 0]])
    with pytest.raises(ValidationError, match="merge_agreement"):
        InstanceConfig(merge_agreement=1.5)


def test_person_classes_from_kinds_or_names():
    assert person_classes(["head", "ball", "wall"], ["body", "object", "object"]).tolist() == [0]
    assert person_classes(["head", "ball", "person"]).tolist() == [0, 2]
    with pytest.raises(ValidationError, match="kinds"):
        person_classes(["head"], ["body", "body"])


def test_instance_accuracy_matches_ids_one_to_one():
    true = np.array([0, 0, 0, 1, 1, 1, -1])
    # predicted ids swapped relative to the truth, one trajectory wrong, one unassigned
    pred = np.array([1, 1, 0, 0, 0, -1, 0])
    assert match_instances(pred, true) == {1: 0, 0: 1}
    assert instance_accuracy(pred, true) == pytest.approx(4 / 6)
    assert np.isnan(instance_accuracy(pred, np.full(7, -1)))
    with pytest.raises(ValidationError, match="shapes"):
        instance_accuracy(pred, true[:3])


def test_a_short_piece_joins_the_person_whose_mask_it_lies_in():
    """A one-frame trajectory (no rigid partner, a single vote) joins the person whose anchors
    fill the same mask in that image; with no vote it gets no person."""
    labels = np.zeros(12, np.int64)
    a, b = np.arange(0, 5), np.arange(5, 10)
    row = np.concatenate([_chain(a)[0], _chain(b)[0]])
    col = np.concatenate([_chain(a)[1], _chain(b)[1]])
    images = np.arange(4)
    votes = np.concatenate(
        [_votes(a, images, 0), _votes(b, images, 1), [[10, 2, 1]]]  # 10: b's mask in image 2
    )
    cfg = InstanceConfig(min_trajectories=3)
    out = assign_instances(labels, np.array([0]), row, col, np.ones(len(row)), votes, cfg)
    assert out[10] == out[5] != out[0]
    assert out[11] == -1  # never in a mask, no edge: on no known person
