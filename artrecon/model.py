"""The articulated model: rigid links (oriented points) and the joints between them, with JSON I/O.

Frame and units: everything is in the frame of configuration A's reconstruction (the "model frame")
and its units ("model units"); `ArticulatedModel.scale` converts to metres once registration has
set it. `frames` holds named 4x4 poses `T_a_b` (p_a = T_a_b @ p_b), e.g. "T_world_model".

JSON is lossless: float64 arrays are written with Python's shortest round-trip repr, integer and
uint8 arrays keep their dtype, and NaN/inf survive (json's non-standard NaN/Infinity tokens).
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from artrecon._version import __version__
from artrecon.errors import InputError
from artrecon.files import json_dumps, write_text_atomic
from artrecon.procrustes import Similarity

log = logging.getLogger(__name__)

__all__ = ["Link", "Joint", "ArticulatedModel", "JOINT_TYPES", "FORMAT_VERSION"]

JOINT_TYPES = ("revolute", "prismatic")
FORMAT_VERSION = 1


def _array(name: str, value, shape_tail: tuple[int, ...], dtype=float) -> np.ndarray:
    a = np.asarray(value, dtype=dtype)
    if a.ndim != 1 + len(shape_tail) or a.shape[1:] != shape_tail:
        tail = ", ".join(map(str, shape_tail))
        raise ValueError(f"{name} must have shape (n, {tail}), got {a.shape}")
    return a


def _vec3(name: str, value) -> np.ndarray:
    a = np.asarray(value, dtype=float).reshape(-1)
    if a.shape != (3,):
        raise ValueError(f"{name} must have shape (3,), got {np.shape(value)}")
    return a


@dataclass
class Link:
    """One rigid link.

    Attributes
    ----------
    points : (n, 3) float
        Points of the link in the model frame (configuration A).
    match_indices : (n,) int
        For each point, the index of the 3D-3D match it came from, or -1 (e.g. a dense point).
    transform_a_to_b : Similarity
        Maps the link from configuration A to configuration B (p_b ~ T.apply(p_a)).
    colours : (n, 3) uint8, optional
        RGB.
    normals : (n, 3) float, optional
        Unit normals, where known.
    name : str
    observed_in : (n,) int8, optional
        Where each point was seen: 0 in configuration A, 1 in configuration B (a dense point of
        B, carried into configuration A by the link's transform: a part that only B showed).
        None where not recorded (e.g. matches, or a model written before it existed).
    """

    points: np.ndarray
    match_indices: np.ndarray
    transform_a_to_b: Similarity = field(default_factory=Similarity)
    colours: np.ndarray | None = None
    normals: np.ndarray | None = None
    name: str = ""
    observed_in: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.points = _array("Link.points", self.points, (3,))
        n = len(self.points)
        self.match_indices = np.asarray(self.match_indices, dtype=np.int64).reshape(-1)
        if self.match_indices.shape != (n,):
            raise ValueError(
                f"Link.match_indices must have shape ({n},), got {self.match_indices.shape}"
            )
        if self.colours is not None:
            self.colours = _array("Link.colours", self.colours, (3,), dtype=np.uint8)
            if len(self.colours) != n:
                raise ValueError(f"Link.colours must have shape ({n}, 3), got {self.colours.shape}")
        if self.normals is not None:
            self.normals = _array("Link.normals", self.normals, (3,))
            if len(self.normals) != n:
                raise ValueError(f"Link.normals must have shape ({n}, 3), got {self.normals.shape}")
        if self.observed_in is not None:
            self.observed_in = np.asarray(self.observed_in, dtype=np.int8).reshape(-1)
            if self.observed_in.shape != (n,) or not np.isin(self.observed_in, (0, 1)).all():
                raise ValueError(f"Link.observed_in must be ({n},) values 0 (configuration A) or "
                                 f"1 (B), got shape {self.observed_in.shape}")

    @property
    def centroid(self) -> np.ndarray:
        """(3,) float."""
        return self.points.mean(axis=0)

    def __len__(self) -> int:
        return len(self.points)


@dataclass
class Joint:
    """A revolute or prismatic joint between a parent and a child link.

    Attributes
    ----------
    type : str
        "revolute" or "prismatic".
    axis_direction : (3,) float
        Unit vector, model frame. Oriented so that the motion from configuration A to B is
        positive (right-hand rule for revolute).
    axis_point : (3,) float
        A point on the axis, model frame (revolute: the rotation centre nearest the child's
        centroid; prismatic: the smaller link's centroid).
    parent, child : int
        Link indices.
    state_a, state_b : float
        Joint value in configurations A and B: angle in rad (revolute) or displacement in model
        units (prismatic). Configuration A is the zero: state_a = 0, state_b = the change.
    name : str
    relative_transform : Similarity
        Motion of the child relative to the parent, in the model frame (T_parent^-1 T_child).
    residual : float
        How far the relative motion is from a pure single joint (model units; revolute: slide
        along the axis, prismatic: rotation-induced displacement of the child).
    confidence : dict
        The evidence behind the joint (artrecon.confidence: inliers, residuals, motion against
        noise, bootstrap spread of the axis, score in [0, 1], registration agreement); empty when
        not assessed (e.g. a model written before confidence existed).
    """

    type: str
    axis_direction: np.ndarray
    axis_point: np.ndarray
    parent: int
    child: int
    state_a: float = 0.0
    state_b: float = 0.0
    name: str = ""
    relative_transform: Similarity = field(default_factory=Similarity)
    residual: float = 0.0
    confidence: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.type not in JOINT_TYPES:
            raise ValueError(f"Joint.type must be one of {JOINT_TYPES}, got {self.type!r}")
        self.axis_direction = _vec3("Joint.axis_direction", self.axis_direction)
        norm = np.linalg.norm(self.axis_direction)
        if not np.isfinite(norm) or norm == 0:
            raise ValueError(f"Joint.axis_direction must be non-zero, got {self.axis_direction}")
        if abs(norm - 1.0) > 1e-9:
            self.axis_direction = self.axis_direction / norm
        self.axis_point = _vec3("Joint.axis_point", self.axis_point)
        self.parent = int(self.parent)
        self.child = int(self.child)
        self.state_a = float(self.state_a)
        self.state_b = float(self.state_b)
        self.residual = float(self.residual)
        self.confidence = dict(self.confidence or {})
        if not self.name:
            self.name = f"joint_{self.parent}_{self.child}"

    @property
    def motion(self) -> float:
        """state_b - state_a."""
        return self.state_b - self.state_a


@dataclass
class ArticulatedModel:
    """Links, joints (a tree rooted at `root`), scale and named frames.

    Attributes
    ----------
    links : list of Link
    joints : list of Joint
        One per non-root link; each joint's child is that link.
    scale : float
        Metres per model unit (1.0 until registration sets it; see `scale_known`).
    frames : dict of str -> (4, 4) float
        Named poses T_a_b, e.g. "T_world_model".
    root : int
        Index of the root link (the largest).
    scale_a_to_b : float
        Common similarity scale between the two configurations' reconstructions.
    scale_known : bool
        True once `scale` is metric.
    metadata : dict
        JSON-serialisable provenance (seed, config, counts...).
    """

    links: list[Link]
    joints: list[Joint]
    scale: float = 1.0
    frames: dict[str, np.ndarray] = field(default_factory=dict)
    root: int = 0
    scale_a_to_b: float = 1.0
    scale_known: bool = False
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.links)
        for j in self.joints:
            for end in (j.parent, j.child):
                if not 0 <= end < n:
                    raise ValueError(f"joint {j.name!r} refers to link {end}, model has {n} links")
        if n and not 0 <= self.root < n:
            raise ValueError(f"root must be a link index in [0, {n}), got {self.root}")
        frames = {}
        for name, m in self.frames.items():
            m = np.asarray(m, dtype=float)
            if m.shape != (4, 4):
                raise ValueError(f"frame {name!r} must have shape (4, 4), got {m.shape}")
            frames[name] = m
        self.frames = frames

    @classmethod
    def from_segmentation(
        cls,
        points_a: np.ndarray,
        segmentation,
        joints: list[Joint],
        colours: np.ndarray | None = None,
        normals: np.ndarray | None = None,
        metadata: dict | None = None,
    ) -> ArticulatedModel:
        """Model whose links are the segmented matches (configuration A).

        Parameters
        ----------
        points_a : (n, 3) float
            The matches' points in configuration A (as given to segment_links).
        segmentation : Segmentation
        joints : list of Joint
            From estimate_joints; the root is the link that is nobody's child.
        colours : (n, 3) uint8, optional
        normals : (n, 3) float, optional
        metadata : dict, optional
        """
        points_a = np.asarray(points_a, dtype=float)
        labels = np.asarray(segmentation.labels)
        if points_a.shape != (len(labels), 3):
            raise ValueError(f"points_a must have shape ({len(labels)}, 3), got {points_a.shape}")
        links = []
        for k, transform in enumerate(segmentation.transforms):
            idx = np.flatnonzero(labels == k)
            links.append(
                Link(
                    points=points_a[idx],
                    match_indices=idx,
                    transform_a_to_b=transform,
                    colours=None if colours is None else np.asarray(colours)[idx],
                    normals=None if normals is None else np.asarray(normals)[idx],
                    name=f"link_{k}",
                )
            )
        children = {j.child for j in joints}
        roots = [k for k in range(len(links)) if k not in children]
        return cls(
            links=links,
            joints=list(joints),
            root=roots[0] if roots else 0,
            scale_a_to_b=float(segmentation.scale),
            metadata=dict(metadata or {}),
        )

    def parent_of(self, link: int) -> int | None:
        for j in self.joints:
            if j.child == link:
                return j.parent
        return None

    def children_of(self, link: int) -> list[int]:
        return [j.child for j in self.joints if j.parent == link]

    # --- JSON --------------------------------------------------------------------------------

    def to_dict(self) -> dict:
        return {
            "format": "artrecon.ArticulatedModel",
            "version": FORMAT_VERSION,
            "scale": self.scale,
            "scale_known": self.scale_known,
            "scale_a_to_b": self.scale_a_to_b,
            "root": self.root,
            "frames": {k: _encode(v) for k, v in self.frames.items()},
            "links": [
                {
                    "name": lk.name,
                    "points": _encode(lk.points),
                    "match_indices": _encode(lk.match_indices),
                    "colours": _encode(lk.colours),
                    "normals": _encode(lk.normals),
                    "observed_in": _encode(lk.observed_in),
                    "transform_a_to_b": lk.transform_a_to_b.to_dict(),
                }
                for lk in self.links
            ],
            "joints": [joint_to_dict(j) for j in self.joints],
            "metadata": self.metadata,
        }

    @classmethod
    def from_dict(cls, d: dict) -> ArticulatedModel:
        """The model of a dict written by :meth:`to_dict`.

        Raises
        ------
        InputError
            Not a model of this format (naming what is there instead), a model of a newer
            format version (upgrade artrecon), or a malformed element (naming it: ``links[2]
            .points``, ``joints[0]``...).
        """
        if not isinstance(d, dict):
            raise InputError(f"not an artrecon articulated model: the JSON holds a "
                             f"{type(d).__name__}, not an object with \"format\": "
                             "\"artrecon.ArticulatedModel\"; pass the model.json a "
                             "reconstruction wrote")
        if d.get("format") != "artrecon.ArticulatedModel":
            raise InputError(
                f"not an artrecon articulated model (format={d.get('format')!r}); expected a file "
                "written by ArticulatedModel.save"
            )
        version = d.get("version")
        if isinstance(version, int) and not isinstance(version, bool) and \
                version > FORMAT_VERSION:
            raise InputError(
                f"the model is in format version {version}, written by a newer artrecon; this "
                f"artrecon ({__version__}) reads version {FORMAT_VERSION}: upgrade artrecon "
                "(pip install --upgrade artrecon) to read it")
        if version != FORMAT_VERSION:
            raise InputError(
                f"articulated model format version {version!r} is not supported (this "
                f"artrecon reads version {FORMAT_VERSION}); reconstruct the model again with "
                "this artrecon"
            )
        where = "the model"
        try:
            links = []
            for i, lk in enumerate(_items(d, "links")):
                where = f"links[{i}]"
                links.append(Link(
                    points=_decode(lk["points"]),
                    match_indices=_decode(lk["match_indices"]),
                    transform_a_to_b=Similarity.from_dict(lk["transform_a_to_b"]),
                    colours=_decode(lk["colours"]),
                    normals=_decode(lk["normals"]),
                    name=lk["name"],
                    observed_in=_decode(lk.get("observed_in")),
                ))
            joints = []
            for i, j in enumerate(_items(d, "joints")):
                where = f"joints[{i}]"
                joints.append(joint_from_dict(j))
            where = "the model's scale, frames or root"
            return cls(
                links=links,
                joints=joints,
                scale=float(d["scale"]),
                frames={k: _decode(v) for k, v in d["frames"].items()},
                root=int(d["root"]),
                scale_a_to_b=float(d["scale_a_to_b"]),
                scale_known=bool(d["scale_known"]),
                metadata=d.get("metadata", {}),
            )
        except InputError:
            raise
        except KeyError as exc:
            raise InputError(f"{where}: missing key {exc}; the file is damaged or was not "
                             "written by artrecon: reconstruct again or restore it") from exc
        except (TypeError, ValueError, AttributeError, IndexError) as exc:
            raise InputError(f"{where} is malformed ({exc}); the file is damaged or was not "
                             "written by artrecon: reconstruct again or restore it") from exc

    def save(self, path: str | Path) -> Path:
        """Write the model as JSON (lossless); returns the path."""
        path = Path(path)
        # whole or not at all: a run killed while writing leaves the old file, never half a model
        write_text_atomic(path, json_dumps(self.to_dict()))  # its point lists one line each
        log.info("saved articulated model (%d links, %d joints) to %s",
                 len(self.links), len(self.joints), path)
        return path

    @classmethod
    def load(cls, path: str | Path) -> ArticulatedModel:
        """Read a model written by `save` (InputError naming the file and what is wrong)."""
        path = Path(path)
        if path.is_dir():
            raise InputError(f"{path} is a folder; name the model file, e.g. "
                             f"{path / 'model.json'}")
        if not path.is_file():
            raise InputError(
                f"articulated model file {path} does not exist; run the reconstruction first"
            )
        try:
            d = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise InputError(f"{path} is not valid JSON ({exc}); pass the model.json a "
                             "reconstruction wrote (reconstruct again if it is damaged)") from exc
        try:
            return cls.from_dict(d)
        except InputError as exc:
            raise InputError(f"{path}: {exc}") from exc


def joint_to_dict(j: Joint) -> dict:
    """A joint as model.json holds it (lossless: JSON floats read back exactly)."""
    return {
        "name": j.name,
        "type": j.type,
        "axis_direction": j.axis_direction.tolist(),
        "axis_point": j.axis_point.tolist(),
        "parent": j.parent,
        "child": j.child,
        "state_a": j.state_a,
        "state_b": j.state_b,
        "relative_transform": j.relative_transform.to_dict(),
        "residual": j.residual,
        "confidence": j.confidence,
    }


def joint_from_dict(j: dict) -> Joint:
    """The joint of a dict written by :func:`joint_to_dict` (KeyError, TypeError, ValueError
    when malformed)."""
    return Joint(
        type=j["type"],
        axis_direction=np.array(j["axis_direction"], dtype=float),
        axis_point=np.array(j["axis_point"], dtype=float),
        parent=j["parent"],
        child=j["child"],
        state_a=j["state_a"],
        state_b=j["state_b"],
        name=j["name"],
        relative_transform=Similarity.from_dict(j["relative_transform"]),
        residual=j["residual"],
        confidence=j.get("confidence") or {},  # absent in files before confidence
    )


def _encode(a: np.ndarray | None):
    if a is None:
        return None
    a = np.asarray(a)
    return {"dtype": a.dtype.str, "shape": list(a.shape), "data": a.reshape(-1).tolist()}


def _items(d: dict, key: str) -> list:
    """``d[key]``, which must be a list (TypeError otherwise: a malformed model)."""
    items = d[key]
    if not isinstance(items, list):
        raise TypeError(f"{key!r} must be a list, got a {type(items).__name__}")
    return items


def _decode(d) -> np.ndarray | None:
    if d is None:
        return None
    return np.array(d["data"], dtype=np.dtype(d["dtype"])).reshape(d["shape"])
