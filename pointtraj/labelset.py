"""Label sets: the K classes of a capture, their display colours, and recogniser mappings.

A capture's ``labels.toml`` (see ``data_specs/semantic_map.md``) lists the classes in class-index
order and says how each recogniser's own output names map onto them::

    [[classes]]
    name = "head"
    color = [230, 25, 75]
    kind = "body"            # optional: "body" (default), "object" or "instance"

    [[classes]]
    name = "ball"
    color = [255, 225, 25]
    kind = "object"

    [recognizers.object-detector]
    map = { "sports ball" = "ball" }

    [[joints]]               # optional: the body-part adjacency (pointtraj.segments)
    name = "neck"
    parts = ["torso", "head"]

A ``[recognizers.<name>]`` table may carry other keys besides ``map`` (for example a model path);
they are kept verbatim in :attr:`LabelSet.recognizer_options`.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import FileFormatError, ValidationError

__all__ = [
    "LabelSet",
    "KINDS",
    "BODY_PARTS",
    "BODY_JOINTS",
    "body_joints",
    "load_labelset",
    "save_labelset",
]

logger = logging.getLogger(__name__)

#: Valid values of a class's ``kind``.
KINDS: tuple[str, ...] = ("body", "object", "instance")

#: The body-part classes of the synthetic figures, in the default class order.
BODY_PARTS: tuple[str, ...] = (
    "head",
    "torso",
    "left_upper_arm",
    "right_upper_arm",
    "left_forearm",
    "right_forearm",
    "left_hand",
    "right_hand",
    "left_thigh",
    "right_thigh",
    "left_shin",
    "right_shin",
    "left_foot",
    "right_foot",
)

#: The joints between adjacent body parts of the synthetic figures: (name, parent part, child
#: part). The joint is the child's proximal end (``pointtraj.synth.figure``: every part's local
#: origin is its proximal joint).
BODY_JOINTS: tuple[tuple[str, str, str], ...] = (
    ("neck", "torso", "head"),
    *(
        joint
        for side in ("left", "right")
        for joint in (
            (f"{side}_shoulder", "torso", f"{side}_upper_arm"),
            (f"{side}_elbow", f"{side}_upper_arm", f"{side}_forearm"),
            (f"{side}_wrist", f"{side}_forearm", f"{side}_hand"),
            (f"{side}_hip", "torso", f"{side}_thigh"),
            (f"{side}_knee", f"{side}_thigh", f"{side}_shin"),
            (f"{side}_ankle", f"{side}_shin", f"{side}_foot"),
        )
    ),
)


def body_joints(names: Sequence[str]) -> tuple[tuple[str, str, str], ...]:
    """The joints of :data:`BODY_JOINTS` whose two parts are both among ``names``.

    Examples
    --------
    >>> body_joints(["torso", "head", "ball"])
    (('neck', 'torso', 'head'),)
    """
    have = set(names)
    return tuple(j for j in BODY_JOINTS if j[1] in have and j[2] in have)


# Distinct display colours (a qualitative palette), one per default class.
_DEFAULT_COLORS: tuple[tuple[int, int, int], ...] = (
    (230, 25, 75),
    (60, 180, 75),
    (0, 130, 200),
    (245, 130, 48),
    (145, 30, 180),
    (70, 240, 240),
    (240, 50, 230),
    (210, 245, 60),
    (250, 190, 212),
    (0, 128, 128),
    (220, 190, 255),
    (170, 110, 40),
    (128, 0, 0),
    (170, 255, 195),
    (255, 225, 25),
    (128, 128, 0),
)


@dataclass(frozen=True, eq=False)
class LabelSet:
    """The K classes of a capture.

    Parameters
    ----------
    names : sequence of str
        Class names in class-index order; unique and non-empty.
    colors : (K, 3) uint8 ndarray
        Display colour of each class, RGB 0-255.
    kinds : sequence of str, optional
        ``"body"``, ``"object"`` or ``"instance"`` per class (default all ``"body"``).
    recognizers : mapping of str to mapping of str to str, optional
        Per recogniser name, its output name -> class name.
    recognizer_options : mapping of str to mapping, optional
        Per recogniser name, other keys of its ``[recognizers.<name>]`` table.
    joints : sequence of (str, str, str), optional
        The body-part adjacency: ``(joint name, parent class, child class)`` per joint
        (``[[joints]]`` of labels.toml; :mod:`pointtraj.segments` finds their centres).

    Raises
    ------
    ValidationError
        On duplicate or empty names, bad colours, unknown kinds, a mapping onto an unknown
        class, or a joint naming an unknown class, the same class twice or a name twice.

    Examples
    --------
    >>> labels = LabelSet(["head", "ball"], [[255, 0, 0], [0, 0, 255]], kinds=["body", "object"])
    >>> labels.index("ball"), len(labels)
    (1, 2)
    """

    names: tuple[str, ...]
    colors: np.ndarray
    kinds: tuple[str, ...] = ()
    recognizers: Mapping[str, Mapping[str, str]] = field(default_factory=dict)
    recognizer_options: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    joints: tuple[tuple[str, str, str], ...] = ()

    def __post_init__(self) -> None:
        names = tuple(str(n) for n in self.names)
        if not names:
            raise ValidationError("names: a label set needs at least one class")
        for n in names:
            if not n.strip():
                raise ValidationError("names: class names must be non-empty")
        seen: set[str] = set()
        for n in names:
            if n in seen:
                raise ValidationError(f"names: duplicate class name {n!r}")
            seen.add(n)
        colors = np.asarray(self.colors)
        if colors.shape != (len(names), 3):
            raise ValidationError(
                f"colors: expected shape ({len(names)}, 3), got {tuple(colors.shape)}"
            )
        if colors.size and (
            not np.issubdtype(colors.dtype, np.number)
            or not np.all(np.isfinite(colors))
            or np.any(colors < 0)
            or np.any(colors > 255)
            or np.any(colors != np.round(colors))
        ):
            raise ValidationError("colors: values must be integers in 0..255")
        colors = colors.astype(np.uint8)
        colors.setflags(write=False)
        kinds = tuple(self.kinds) if len(self.kinds) else ("body",) * len(names)
        if len(kinds) != len(names):
            raise ValidationError(f"kinds: expected {len(names)} values, got {len(kinds)}")
        for n, k in zip(names, kinds):
            if k not in KINDS:
                raise ValidationError(
                    f"kinds: class {n!r} has kind {k!r} (valid: {', '.join(KINDS)})"
                )
        recognizers: dict[str, dict[str, str]] = {}
        for rec, mapping in dict(self.recognizers).items():
            m = {str(k): str(v) for k, v in dict(mapping).items()}
            for out, cls in m.items():
                if cls not in seen:
                    raise ValidationError(
                        f"recognizers.{rec}.map: {out!r} maps to unknown class {cls!r}"
                    )
            recognizers[str(rec)] = m
        options = {str(k): dict(v) for k, v in dict(self.recognizer_options).items()}
        joints = tuple((str(j[0]), str(j[1]), str(j[2])) for j in self.joints)
        joint_names: set[str] = set()
        for jn, parent, child in joints:
            if not jn.strip() or jn in joint_names:
                raise ValidationError(f"joints: empty or duplicate joint name {jn!r}")
            joint_names.add(jn)
            for part in (parent, child):
                if part not in seen:
                    raise ValidationError(f"joints: {jn!r} names unknown class {part!r}")
            if parent == child:
                raise ValidationError(f"joints: {jn!r} joins class {parent!r} to itself")
        object.__setattr__(self, "joints", joints)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "colors", colors)
        object.__setattr__(self, "kinds", kinds)
        object.__setattr__(self, "recognizers", recognizers)
        object.__setattr__(self, "recognizer_options", options)

    def __len__(self) -> int:
        return len(self.names)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, LabelSet):
            return NotImplemented
        return (
            self.names == other.names
            and np.array_equal(self.colors, other.colors)
            and self.kinds == other.kinds
            and self.recognizers == other.recognizers
            and self.recognizer_options == other.recognizer_options
            and self.joints == other.joints
        )

    def __repr__(self) -> str:
        return f"LabelSet({len(self)} classes: {', '.join(self.names)})"

    @property
    def num_classes(self) -> int:
        """K, the number of classes."""
        return len(self.names)

    def index(self, name: str) -> int:
        """Class index of ``name``.

        Raises
        ------
        KeyError
            If there is no such class (the message lists the valid names).
        """
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"unknown class {name!r} (classes: {', '.join(self.names)})") from None

    def indices(self, names: Sequence[str]) -> np.ndarray:
        """Class indices of several names, as an (n,) int64 array."""
        return np.array([self.index(n) for n in names], dtype=np.int64)

    def mapping(self, recognizer: str) -> dict[str, str]:
        """A recogniser's output name -> class name mapping (empty if labels.toml has none)."""
        return dict(self.recognizers.get(recognizer, {}))

    def mapping_indices(self, recognizer: str) -> dict[str, int]:
        """A recogniser's output name -> class index mapping."""
        return {out: self.index(cls) for out, cls in self.mapping(recognizer).items()}

    def options(self, recognizer: str) -> dict[str, Any]:
        """The non-``map`` keys of ``[recognizers.<recognizer>]`` (empty if absent)."""
        return dict(self.recognizer_options.get(recognizer, {}))

    def classes_of_kind(self, kind: str) -> np.ndarray:
        """Indices (n,) int64 of the classes of one kind (``"body"``, ``"object"``, ...)."""
        if kind not in KINDS:
            raise ValidationError(f"kind: must be one of {', '.join(KINDS)}, got {kind!r}")
        return np.array([i for i, k in enumerate(self.kinds) if k == kind], dtype=np.int64)

    @classmethod
    def default(cls) -> LabelSet:
        """The default label set: the 14 body parts, then ``ball`` and ``racket`` (objects),
        with the body joints :data:`BODY_JOINTS`.

        Used when a capture has no ``labels.toml``.

        Examples
        --------
        >>> labels = LabelSet.default()
        >>> labels.names[:2], labels.index("ball"), labels.kinds[-1]
        (('head', 'torso'), 14, 'object')
        """
        names = (*BODY_PARTS, "ball", "racket")
        kinds = ("body",) * len(BODY_PARTS) + ("object", "object")
        colors = np.array(_DEFAULT_COLORS[: len(names)], dtype=np.uint8)
        return cls(names, colors, kinds, joints=BODY_JOINTS)

    @classmethod
    def load(cls, path: str | os.PathLike) -> LabelSet:
        """Read a ``labels.toml`` file.

        Raises
        ------
        FileFormatError
            Naming the file and the field: missing file, bad TOML, no classes, a duplicate
            name, a bad colour or kind, a mapping onto an unknown class, a bad joint.
        """
        from .config import load_toml

        path = Path(path)
        data = load_toml(path)
        unknown = sorted(set(data) - {"classes", "recognizers", "joints"})
        if unknown:
            raise FileFormatError(path, f"unknown top-level key {unknown[0]!r}")
        classes = data.get("classes")
        if not isinstance(classes, list) or not classes:
            raise FileFormatError(path, "needs at least one [[classes]] table")
        names: list[str] = []
        colors: list[list[int]] = []
        kinds: list[str] = []
        for i, entry in enumerate(classes):
            where = f"classes[{i}]"
            if not isinstance(entry, dict):
                raise FileFormatError(path, f"{where}: expected a table")
            extra = sorted(set(entry) - {"name", "color", "kind"})
            if extra:
                raise FileFormatError(
                    path, f"{where}: unknown key {extra[0]!r} (valid: color, kind, name)"
                )
            name = entry.get("name")
            if not isinstance(name, str) or not name.strip():
                raise FileFormatError(path, f"{where}.name: expected a non-empty string")
            if name in names:
                raise FileFormatError(path, f"{where}.name: duplicate class name {name!r}")
            color = entry.get("color")
            if (
                not isinstance(color, list)
                or len(color) != 3
                or not all(isinstance(c, int) and not isinstance(c, bool) for c in color)
                or not all(0 <= c <= 255 for c in color)
            ):
                raise FileFormatError(
                    path, f"{where}.color: expected [r, g, b] integers in 0..255, got {color!r}"
                )
            kind = entry.get("kind", "body")
            if kind not in KINDS:
                raise FileFormatError(
                    path, f"{where}.kind: must be one of {', '.join(KINDS)}, got {kind!r}"
                )
            names.append(name)
            colors.append(color)
            kinds.append(kind)
        recs = data.get("recognizers", {})
        if not isinstance(recs, dict):
            raise FileFormatError(path, "recognizers: expected a table")
        maps: dict[str, dict[str, str]] = {}
        options: dict[str, dict[str, Any]] = {}
        for rec, table in recs.items():
            if not isinstance(table, dict):
                raise FileFormatError(path, f"recognizers.{rec}: expected a table")
            m = table.get("map", {})
            if not isinstance(m, dict) or not all(isinstance(v, str) for v in m.values()):
                raise FileFormatError(
                    path, f"recognizers.{rec}.map: expected a table of output name = class name"
                )
            for out, target in m.items():
                if target not in names:
                    raise FileFormatError(
                        path,
                        f"recognizers.{rec}.map: {out!r} maps to unknown class {target!r}",
                    )
            if m:
                maps[rec] = dict(m)
            rest = {k: v for k, v in table.items() if k != "map"}
            if rest:
                options[rec] = rest
        joints = _load_joints(path, data.get("joints", []))
        try:
            return cls(
                tuple(names), np.array(colors, dtype=np.uint8), tuple(kinds), maps, options, joints
            )
        except ValidationError as exc:
            raise FileFormatError(path, str(exc)) from None

    def save(self, path: str | os.PathLike) -> None:
        """Write this label set as ``labels.toml`` (atomically); :meth:`load` reads it back."""
        from .config import save_toml

        doc: dict[str, Any] = {
            "classes": [
                {"name": name, "color": [int(v) for v in color], "kind": kind}
                for name, color, kind in zip(self.names, self.colors, self.kinds)
            ]
        }
        recognizers = {}
        for rec in sorted(set(self.recognizers) | set(self.recognizer_options)):
            table = dict(self.recognizer_options.get(rec, {}))
            if self.recognizers.get(rec):
                table["map"] = dict(self.recognizers[rec])
            recognizers[rec] = table
        if recognizers:
            doc["recognizers"] = recognizers
        if self.joints:
            doc["joints"] = [
                {"name": n, "parts": [parent, child]} for n, parent, child in self.joints
            ]
        save_toml(path, doc, comment="pointtraj label set: classes in class-index order")


def _load_joints(path: Path, joints: Any) -> tuple[tuple[str, str, str], ...]:
    """The ``[[joints]]`` tables of labels.toml as (name, parent, child) triples.

    Raises
    ------
    FileFormatError
        Naming the file and the table: not a list of tables, an unknown key, a bad name or
        ``parts`` that is not two class names.
    """
    if not isinstance(joints, list):
        raise FileFormatError(path, "joints: expected [[joints]] tables")
    out = []
    for i, entry in enumerate(joints):
        where = f"joints[{i}]"
        if not isinstance(entry, dict):
            raise FileFormatError(path, f"{where}: expected a table")
        extra = sorted(set(entry) - {"name", "parts"})
        if extra:
            raise FileFormatError(path, f"{where}: unknown key {extra[0]!r} (valid: name, parts)")
        name, parts = entry.get("name"), entry.get("parts")
        if not isinstance(name, str) or not name.strip():
            raise FileFormatError(path, f"{where}.name: expected a non-empty string")
        if not (
            isinstance(parts, list) and len(parts) == 2 and all(isinstance(p, str) for p in parts)
        ):
            raise FileFormatError(
                path, f"{where}.parts: expected [parent, child] class names, got {parts!r}"
            )
        out.append((name, parts[0], parts[1]))
    return tuple(out)


def check_class_names(
    labels_toml: str | os.PathLike,
    expected: Sequence[str],
    other: str | os.PathLike,
    names: Sequence[str],
) -> None:
    """Refuse a file whose classes (names or order) are not those of ``labels.toml``.

    A label is a class index, so a ``labels.toml`` edited after a stage ran (two names
    swapped, a class added) would silently rename that stage's labels.

    Parameters
    ----------
    labels_toml : path-like
        The capture's label set file.
    expected : sequence of str
        Its class names, in class-index order.
    other : path-like
        The file made with a label set (``semantic_map.npz``, ``labels.npz``).
    names : sequence of str
        That file's class names.

    Raises
    ------
    FileFormatError
        Naming ``labels.toml``, the other file and the first class that differs.
    """
    expected, names = [str(n) for n in expected], [str(n) for n in names]
    if expected == names:
        return
    if len(expected) != len(names):
        what = f"has {len(expected)} classes, {other} {len(names)}"
    else:
        k = next(i for i, (a, b) in enumerate(zip(expected, names)) if a != b)
        what = f"class {k} is {expected[k]!r}, but {names[k]!r} in {other}"
    raise FileFormatError(
        labels_toml,
        f"{what}: the classes changed after {Path(other).name} was made "
        "(restore labels.toml or rerun the stages from `pointtraj semantics`)",
    )


def load_labelset(path: str | os.PathLike) -> LabelSet:
    """Read ``labels.toml`` (same as :meth:`LabelSet.load`)."""
    return LabelSet.load(path)


def save_labelset(labels: LabelSet, path: str | os.PathLike) -> None:
    """Write ``labels.toml`` (same as :meth:`LabelSet.save`)."""
    labels.save(path)
