"""Foxglove 3-D scene messages for episode logs: the static track and the moving cars.

Builds `foxglove.messages` protobuf objects from plain arrays; writing them is the recorder's job.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from foxglove.messages import (
    Color,
    CubePrimitive,
    FrameTransform,
    FrameTransforms,
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    Timestamp,
    TriangleListPrimitive,
    Vector3,
)

from d2a_core.sim.episode_log.config import Colour, EpisodeLogConfig
from d2a_core.sim.rotation import euler_to_quaternion

WORLD_FRAME = "world"


def _as_points(name: str, points: object) -> np.ndarray:
    """Return a finite float64 (N, 3) copy of a polyline; (N, 2) input gets z = 0."""
    array = np.array(points, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] not in (2, 3):
        raise ValueError(f"{name} must be an (N, 3) or (N, 2) array, got shape {array.shape}")
    if array.shape[1] == 2:
        array = np.concatenate([array, np.zeros((len(array), 1))], axis=1)
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} contains non-finite coordinates")
    return array


@dataclass
class StaticScene:
    """Track geometry drawn once at the start of a log, in the `world` frame (metres).

    Polylines are drawn as given: pass a closed loop with its first point repeated at the end.
    `barriers` holds (base points (M, 3), wall height) pairs; `finish_line` is usually its two end
    points. When the left and right edges have the
    same number of points, the road surface between them is drawn as triangles.
    """

    track_name: str
    left_edge: np.ndarray
    right_edge: np.ndarray
    barriers: list[tuple[np.ndarray, float]]
    finish_line: np.ndarray
    centreline: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.left_edge = _as_points("left_edge", self.left_edge)
        self.right_edge = _as_points("right_edge", self.right_edge)
        self.finish_line = _as_points("finish_line", self.finish_line)
        if self.centreline is not None:
            self.centreline = _as_points("centreline", self.centreline)
        checked: list[tuple[np.ndarray, float]] = []
        for index, (base, height) in enumerate(self.barriers):
            if not (math.isfinite(height) and height > 0):
                raise ValueError(f"barriers[{index}] height must be positive, got {height}")
            checked.append((_as_points(f"barriers[{index}]", base), float(height)))
        self.barriers = checked


@dataclass(frozen=True, slots=True)
class CarPose:
    """Where one car is and how to draw it.

    (x, y, z) is the centre of the car body in the world frame (m); yaw, pitch and roll are
    intrinsic z-y-x Euler angles (rad). Size and colour default to the recorder's config.
    """

    x: float
    y: float
    z: float
    yaw: float
    pitch: float = 0.0
    roll: float = 0.0
    length: float | None = None
    width: float | None = None
    height: float | None = None
    colour: Colour | None = None


def timestamp_from_ns(time_ns: int) -> Timestamp:
    """Foxglove timestamp for a log time in nanoseconds."""
    return Timestamp(time_ns // 1_000_000_000, time_ns % 1_000_000_000)


def _color(colour: Colour) -> Color:
    return Color(r=colour[0], g=colour[1], b=colour[2], a=colour[3])


def _point_list(points: np.ndarray, lift: float = 0.0) -> list[Point3]:
    return [Point3(x=x, y=y, z=z + lift) for x, y, z in points.tolist()]


def _line(points: np.ndarray, colour: Colour, config: EpisodeLogConfig) -> LinePrimitive:
    return LinePrimitive(
        type=LinePrimitiveLineType.LineStrip,
        pose=Pose(position=Vector3(), orientation=Quaternion(w=1.0)),
        thickness=config.edge_line_width_m,
        points=_point_list(points, config.overlay_lift_m),
        color=_color(colour),
    )


def _strip_triangles(first: np.ndarray, second: np.ndarray, colour: Colour) -> TriangleListPrimitive:
    """Triangles tiling the quad strip between two equally long polylines."""
    count = len(first)
    interleaved = np.empty((2 * count, 3))
    interleaved[0::2] = first
    interleaved[1::2] = second
    indices: list[int] = []
    for i in range(count - 1):
        a, b, c, d = 2 * i, 2 * i + 1, 2 * i + 2, 2 * i + 3
        indices += [a, b, c, b, d, c]
    return TriangleListPrimitive(
        pose=Pose(position=Vector3(), orientation=Quaternion(w=1.0)),
        points=_point_list(interleaved),
        color=_color(colour),
        indices=indices,
    )


def static_scene_update(scene: StaticScene, config: EpisodeLogConfig, time_ns: int) -> SceneUpdate:
    """SceneUpdate with the road, its edges, centreline, finish line and barrier walls."""
    stamp = timestamp_from_ns(time_ns)

    def entity(entity_id: str, **primitives: object) -> SceneEntity:
        return SceneEntity(timestamp=stamp, frame_id=WORLD_FRAME, id=entity_id, **primitives)

    road_lines = [
        _line(scene.left_edge, config.edge_colour, config),
        _line(scene.right_edge, config.edge_colour, config),
    ]
    road_triangles = []
    if len(scene.left_edge) == len(scene.right_edge) and len(scene.left_edge) >= 2:
        road_triangles.append(_strip_triangles(scene.left_edge, scene.right_edge, config.road_colour))
    entities = [entity("track/road", lines=road_lines, triangles=road_triangles)]
    if scene.centreline is not None and len(scene.centreline) >= 2:
        entities.append(
            entity("track/centreline", lines=[_line(scene.centreline, config.centreline_colour, config)])
        )
    if len(scene.finish_line) >= 2:
        entities.append(
            entity("track/finish", lines=[_line(scene.finish_line, config.finish_colour, config)])
        )
    walls, tops = [], []
    for base, height in scene.barriers:
        if len(base) < 2:
            continue
        top = base + np.array([0.0, 0.0, height])
        walls.append(_strip_triangles(base, top, config.barrier_colour))
        tops.append(_line(top, config.barrier_colour, config))
    if walls:
        entities.append(entity("track/barriers", lines=tops, triangles=walls))
    return SceneUpdate(entities=entities)


class CarDrawer:
    """Builds the per-step car cubes and `world -> <car>` transforms, caching sizes and colours."""

    def __init__(self, car_names: list[str], config: EpisodeLogConfig) -> None:
        self._config = config
        palette = config.car_colours
        self._default_colour = {
            name: palette[index % len(palette)] for index, name in enumerate(sorted(car_names))
        }
        self._look: dict[str, tuple[tuple[object, ...], Vector3, Color]] = {}

    def _size_and_colour(self, name: str, pose: CarPose) -> tuple[Vector3, Color]:
        key = (pose.length, pose.width, pose.height, pose.colour)
        cached = self._look.get(name)
        if cached is not None and cached[0] == key:
            return cached[1], cached[2]
        config = self._config
        size = Vector3(
            x=config.car_length_m if pose.length is None else pose.length,
            y=config.car_width_m if pose.width is None else pose.width,
            z=config.car_height_m if pose.height is None else pose.height,
        )
        colour = _color(self._default_colour[name] if pose.colour is None else pose.colour)
        self._look[name] = (key, size, colour)
        return size, colour

    def messages(
        self, cars: Mapping[str, CarPose], time_ns: int
    ) -> tuple[SceneUpdate, FrameTransforms]:
        """Car cubes in the world frame and one transform per car, both stamped `time_ns`."""
        stamp = timestamp_from_ns(time_ns)
        entities, transforms = [], []
        for name, pose in cars.items():
            qx, qy, qz, qw = euler_to_quaternion(pose.yaw, pose.pitch, pose.roll)
            size, colour = self._size_and_colour(name, pose)
            position = Vector3(x=pose.x, y=pose.y, z=pose.z)
            rotation = Quaternion(x=qx, y=qy, z=qz, w=qw)
            cube = CubePrimitive(
                pose=Pose(position=position, orientation=rotation), size=size, color=colour
            )
            entities.append(
                SceneEntity(timestamp=stamp, frame_id=WORLD_FRAME, id=f"car/{name}", cubes=[cube])
            )
            transforms.append(
                FrameTransform(
                    timestamp=stamp,
                    parent_frame_id=WORLD_FRAME,
                    child_frame_id=name,
                    translation=position,
                    rotation=rotation,
                )
            )
        return SceneUpdate(entities=entities), FrameTransforms(transforms=transforms)
