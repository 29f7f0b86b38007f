"""The 3-D race world in pybullet: road with elevation, barriers, car bodies, contacts, rays, camera.

pybullet is only the *world* here. The cars' motion comes from the project's own single-track model;
each control step the caller places the car boxes (``set_car_pose``) and asks what touches
(``collisions``). Nothing is ever simulated with ``stepSimulation``.

Geometry (all static, built once from plain arrays so this module does not depend on the track
module): the road is a triangle strip between the left and right edge polylines and follows their
elevation; all barriers form one concave triangle mesh of walls with a thickness; the runoff,
edge lines and a ground plane are visual only, so that off-track cars still render sensibly.

Collision filtering (Bullet accepts a pair when ``groupA & maskB`` and ``groupB & maskA``): bit 0
is reserved for ray queries (pybullet casts rays with group 1), so every body's mask has it and no
body is in it. The road is in its own group and its mask holds only the ray bit, so nothing ever
pairs with it; each car has a group bit of its own, so ray casts of one car can skip its own body.

Contacts are read with ``getClosestPoints`` per pair (stateless, ~2 us a pair). The cheaper
``performCollisionDetection`` + ``getContactPoints`` reuses Bullet's persistent contact manifolds,
which keep stale points (metres of "penetration") after the bodies are teleported, so it reports
false contacts a few times in 10,000 random placements.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from d2a_core.sim.quiet_pybullet import pb
from d2a_core.sim.world_config import Rgba, WorldConfig

# Collision filter bits (see module docstring).
_RAY_BIT = 1
_ROAD_GROUP = 2
_BARRIER_GROUP = 4
_FIRST_CAR_BIT = 8
MAX_CARS = 24  # car bits must fit the 32-bit signed filter words

# pybullet's per-shape limits on vertex and index counts of meshes passed from memory.
_MAX_MESH_VERTICES = 131072
_MAX_MESH_INDICES = 524288
_VISUAL_CHUNK_QUADS = 16384  # 4 vertices per quad: stays well under the vertex limit


@dataclass(slots=True)
class Collisions:
    """What the cars touch at their current poses.

    ``car_car`` says whether any two cars touch and ``car_pairs`` lists the touching pairs
    ``(i, j)`` with ``i < j``; ``car_barrier[i]`` says whether car ``i`` touches a barrier (or, with
    sweeping on, crossed one since its previous pose). Unpacks as ``car_car, car_barrier``.
    """

    car_car: bool
    car_barrier: tuple[bool, ...]
    car_pairs: tuple[tuple[int, int], ...] = ()

    def involves(self, car: int) -> bool:
        """Whether car ``car`` touches anything (another car or a barrier)."""
        return self.car_barrier[car] or any(car in pair for pair in self.car_pairs)

    def __iter__(self):
        # Lets callers unpack ``car_car, car_barrier = world.collisions()``.
        return iter((self.car_car, list(self.car_barrier)))


class _QuadMesh:
    """Flat-shaded quads (4 own vertices each) collected in numpy arrays, oriented by a facing hint."""

    def __init__(self) -> None:
        self._corners: list[np.ndarray] = []  # (K, 4, 3)
        self._facing: list[np.ndarray] = []  # (K, 3)

    def add(self, a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, facing: np.ndarray) -> None:
        """Add quads with corners ``a, b, c, d`` ((K, 3) each, in rim order) facing ``facing``."""
        corners = np.stack([a, b, c, d], axis=1).astype(float)
        self._corners.append(corners)
        self._facing.append(np.broadcast_to(np.asarray(facing, dtype=float), (len(corners), 3)))

    def chunks(self, max_quads: int) -> list[tuple[list, list, list]]:
        """``(vertices, indices, normals)`` lists for pybullet, at most ``max_quads`` quads each."""
        if not self._corners:
            return []
        corners = np.concatenate(self._corners)
        facing = np.concatenate(self._facing)
        normal = np.cross(corners[:, 2] - corners[:, 0], corners[:, 3] - corners[:, 1])
        flip = np.einsum("ij,ij->i", normal, facing) < 0
        corners[flip] = corners[flip][:, ::-1]  # reversing the rim reverses the winding
        normal[flip] *= -1.0
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        out = []
        for start in range(0, len(corners), max_quads):
            part = corners[start : start + max_quads]
            k = len(part)
            base = 4 * np.arange(k)[:, None]
            indices = (base + np.array([0, 1, 2, 0, 2, 3])).ravel()
            normals = np.repeat(normal[start : start + max_quads], 4, axis=0)
            out.append((part.reshape(-1, 3).tolist(), indices.tolist(), normals.tolist()))
        return out


def _horizontal_unit(v: np.ndarray) -> np.ndarray:
    h = v.copy()
    h[..., 2] = 0.0
    return h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-12)


def _polyline_left_normals(points: np.ndarray) -> np.ndarray:
    """Horizontal unit normals (to the left of travel) at each vertex of a polyline."""
    tangent = np.gradient(points[:, :2], axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    return np.stack([-tangent[:, 1], tangent[:, 0], np.zeros(len(points))], axis=1)


def _nearest_points(queries: np.ndarray, points: np.ndarray, block: int = 2048) -> np.ndarray:
    """For each query point, the nearest of ``points`` in the horizontal plane (brute force, blocked)."""
    out = np.empty_like(queries)
    for start in range(0, len(queries), block):
        q = queries[start : start + block, None, :2]
        d2 = np.sum((q - points[None, :, :2]) ** 2, axis=2)
        out[start : start + block] = points[np.argmin(d2, axis=1)]
    return out


def _check_polyline(name: str, points: np.ndarray, min_points: int = 2) -> np.ndarray:
    arr = np.asarray(points, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] < min_points:
        raise ValueError(f"{name} must be an (N, 3) array with N >= {min_points}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} contains non-finite values")
    return arr


class RaceWorld:
    """A pybullet world (own DIRECT client) with a road, barriers and ``n_cars`` car boxes.

    Args:
        left_edge, right_edge: (N, 3) road edge polylines, point ``i`` of one facing point ``i`` of the
            other. For a closed track repeat the first points at the end.
        barriers: ``(base_points (M, 3), height)`` per barrier. The base polyline is the wall's
            road-facing side; the wall's thickness extends away from the road.
        car_size: car box ``(length, width, height)`` in metres.
        n_cars: number of car bodies.
        render_size: default ``(width, height)`` of ``render`` images.
        config: tunable constants; defaults when omitted.
    """

    def __init__(
        self,
        left_edge: np.ndarray,
        right_edge: np.ndarray,
        barriers: Sequence[tuple[np.ndarray, float]] = (),
        car_size: tuple[float, float, float] = (4.6, 1.9, 1.2),
        n_cars: int = 2,
        render_size: tuple[int, int] = (84, 84),
        config: WorldConfig | None = None,
    ) -> None:
        self.config = config or WorldConfig()
        left = _check_polyline("left_edge", left_edge)
        right = _check_polyline("right_edge", right_edge)
        if left.shape != right.shape:
            raise ValueError(f"left_edge {left.shape} and right_edge {right.shape} must have the same shape")
        if not 1 <= n_cars <= MAX_CARS:
            raise ValueError(f"n_cars must be in [1, {MAX_CARS}], got {n_cars}")
        if len(car_size) != 3 or min(car_size) <= 0:
            raise ValueError(
                f"car_size must be three positive numbers (length, width, height), got {car_size}"
            )
        if len(render_size) != 2 or min(render_size) <= 0:
            raise ValueError(f"render_size must be two positive integers (width, height), got {render_size}")
        checked_barriers = []
        for k, (base, height) in enumerate(barriers):
            if not height > 0:
                raise ValueError(f"barriers[{k}] height must be positive, got {height}")
            checked_barriers.append((_check_polyline(f"barriers[{k}] base points", base), float(height)))

        self.n_cars = n_cars
        self.car_size = tuple(float(v) for v in car_size)
        self.render_size = (int(render_size[0]), int(render_size[1]))
        self._left, self._right = left, right
        all_z = np.concatenate([left[:, 2], right[:, 2]] + [b[:, 2] for b, _ in checked_barriers])
        self._z_low, self._z_high = float(all_z.min()), float(all_z.max())

        self._client: int | None = pb.connect(pb.DIRECT)
        if self._client < 0:
            self._client = None
            raise RuntimeError("could not start a pybullet DIRECT client")
        self._cid = {"physicsClientId": self._client}
        try:
            self.road_body_id = self._build_road()
            self.barrier_body_id = self._build_barriers(checked_barriers)
            self._build_scenery()
            self.car_body_ids = self._build_cars()
        except Exception:
            self.close()
            raise

        self._car_mask_all = sum(_FIRST_CAR_BIT << i for i in range(n_cars))
        # Hot-path constants, read once from the config.
        cfg = self.config
        self._centre_lift = cfg.ground_clearance_m + 0.5 * self.car_size[2]
        self._sweep_lift = cfg.ground_clearance_m + cfg.sweep_height_fraction * self.car_size[2]
        self._contact_distance = cfg.contact_distance_m
        self._sweep_enabled = cfg.sweep_barrier_crossing
        diagonal = math.sqrt(sum(v * v for v in self.car_size))
        self._pair_skip_distance_sq = (diagonal + cfg.contact_distance_m + 0.01) ** 2
        self._sweep_min_sq = (cfg.barrier_thickness_m + min(self.car_size[:2])) ** 2
        self._pose: list[tuple[float, float, float, float, float, float]] = []  # x, y, z, yaw, pitch, roll
        # Sweep-ray point of each car's current pose; None while parked, so no sweep starts there.
        self._sweep_point: list[tuple[float, float, float] | None] = []
        self._centre: list[tuple[float, float, float]] = []  # current box centre per car
        self._sweep_from: list[tuple[float, float, float] | None] = [None] * n_cars
        self._park_cars()

    # ----------------------------------------------------------------------------------------- build

    def _static_body(self, collision: int, visual: int, group: int, mask: int) -> int:
        body = pb.createMultiBody(0.0, collision, visual, **self._cid)
        if collision >= 0:
            pb.setCollisionFilterGroupMask(body, -1, group, mask, **self._cid)
        return body

    def _mesh_shape(self, name: str, vertices: np.ndarray, triangles: np.ndarray) -> int:
        if len(vertices) > _MAX_MESH_VERTICES or 3 * len(triangles) > _MAX_MESH_INDICES:
            raise ValueError(
                f"{name} mesh has {len(vertices)} vertices and {len(triangles)} triangles, over pybullet's "
                f"limits ({_MAX_MESH_VERTICES} vertices, {_MAX_MESH_INDICES // 3} triangles): resample it"
            )
        return pb.createCollisionShape(
            pb.GEOM_MESH,
            vertices=vertices.tolist(),
            indices=triangles.ravel().tolist(),
            flags=pb.GEOM_FORCE_CONCAVE_TRIMESH,
            **self._cid,
        )

    def _visual_bodies(self, mesh: _QuadMesh, colour: Rgba) -> None:
        for vertices, indices, normals in mesh.chunks(_VISUAL_CHUNK_QUADS):
            visual = pb.createVisualShape(
                pb.GEOM_MESH,
                vertices=vertices,
                indices=indices,
                normals=normals,
                rgbaColor=list(colour),
                **self._cid,
            )
            self._static_body(-1, visual, 0, 0)

    def _build_road(self) -> int:
        left, right = self._left, self._right
        n = len(left)
        # Collision strip with shared vertices: rows right (0..n-1) and left (n..2n-1).
        vertices = np.concatenate([right, left])
        i = np.arange(n - 1)
        triangles = np.concatenate([np.stack([i, i + 1, n + i], 1), np.stack([n + i, i + 1, n + i + 1], 1)])
        collision = self._mesh_shape("road", vertices, triangles)
        visual = _QuadMesh()
        visual.add(right[:-1], right[1:], left[1:], left[:-1], (0.0, 0.0, 1.0))
        body = self._static_body(collision, -1, _ROAD_GROUP, _RAY_BIT)
        # The road's own visual is attached as separate visual-only bodies (any size).
        self._visual_bodies(visual, self.config.road_colour)
        return body

    def _build_barriers(self, barriers: list[tuple[np.ndarray, float]]) -> int | None:
        if not barriers:
            return None
        cfg = self.config
        centre = 0.5 * (self._left + self._right)
        vert_blocks, tri_blocks, offset = [], [], 0
        visual = _QuadMesh()
        for base, height in barriers:
            normal = _polyline_left_normals(base)
            # The wall's thickness goes away from the road: flip the normal if the road lies on its side.
            away = base - _nearest_points(base, centre)
            if np.sum(np.einsum("ij,ij->i", normal[:, :2], away[:, :2])) < 0:
                normal = -normal
            down = np.array([0.0, 0.0, cfg.barrier_sink_m])
            up = np.array([0.0, 0.0, height])
            inner_bottom, inner_top = base - down, base + up
            outer = base + cfg.barrier_thickness_m * normal
            outer_bottom, outer_top = outer - down, outer + up
            m = len(base)
            vert_blocks.append(np.concatenate([inner_bottom, inner_top, outer_bottom, outer_top]))
            j = np.arange(m - 1)
            ib, it, ob, ot = j, m + j, 2 * m + j, 3 * m + j
            quads = [(ib, ib + 1, it + 1, it), (ob, ob + 1, ot + 1, ot), (it, it + 1, ot + 1, ot)]
            closed = np.allclose(base[0], base[-1])
            if not closed:  # end caps
                quads.append((np.array([0]), np.array([m]), np.array([3 * m]), np.array([2 * m])))
                quads.append(
                    (np.array([m - 1]), np.array([2 * m - 1]), np.array([4 * m - 1]), np.array([3 * m - 1]))
                )
            for a, b, c, d in quads:
                tri_blocks.append(offset + np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]))
            offset += 4 * m
            # Visual: flat-shaded road-facing side, top and end caps. The back side is left out: it
            # is hardly ever seen and TinyRenderer's cost grows with every triangle in the scene.
            seg_normal = _horizontal_unit(normal[:-1] + normal[1:])
            visual.add(inner_bottom[:-1], inner_bottom[1:], inner_top[1:], inner_top[:-1], -seg_normal)
            visual.add(inner_top[:-1], inner_top[1:], outer_top[1:], outer_top[:-1], (0.0, 0.0, 1.0))
            if not closed:
                tangent0 = _horizontal_unit(base[0] - base[1])
                visual.add(inner_bottom[:1], inner_top[:1], outer_top[:1], outer_bottom[:1], tangent0)
                tangent1 = _horizontal_unit(base[-1] - base[-2])
                visual.add(inner_bottom[-1:], inner_top[-1:], outer_top[-1:], outer_bottom[-1:], tangent1)
        collision = self._mesh_shape("barrier", np.concatenate(vert_blocks), np.concatenate(tri_blocks))
        car_bits = sum(_FIRST_CAR_BIT << i for i in range(self.n_cars))
        body = self._static_body(collision, -1, _BARRIER_GROUP, _RAY_BIT | car_bits)
        self._visual_bodies(visual, cfg.barrier_colour)
        return body

    def _build_scenery(self) -> None:
        """Visual-only runoff strips, edge lines and a ground plane (no collision shapes)."""
        cfg = self.config
        left, right = self._left, self._right
        outward_left = _horizontal_unit(left - right)
        lower = np.array([0.0, 0.0, cfg.runoff_drop_m])
        if cfg.runoff_width_m > 0:
            runoff = _QuadMesh()
            for edge, outward in ((left, outward_left), (right, -outward_left)):
                inner = edge - lower
                outer = inner + cfg.runoff_width_m * outward
                runoff.add(inner[:-1], inner[1:], outer[1:], outer[:-1], (0.0, 0.0, 1.0))
            self._visual_bodies(runoff, cfg.runoff_colour)
        if cfg.edge_line_width_m > 0:
            lines = _QuadMesh()
            lift = np.array([0.0, 0.0, cfg.edge_line_lift_m])
            for edge, inward in ((left, -outward_left), (right, outward_left)):
                outer = edge + lift
                inner = outer + cfg.edge_line_width_m * inward
                lines.add(outer[:-1], outer[1:], inner[1:], inner[:-1], (0.0, 0.0, 1.0))
            self._visual_bodies(lines, cfg.edge_line_colour)
        # Ground: a grid of tiles (one huge quad clips badly in TinyRenderer's near plane).
        xy = np.concatenate([left[:, :2], right[:, :2]])
        lo, hi = xy.min(axis=0) - cfg.ground_margin_m, xy.max(axis=0) + cfg.ground_margin_m
        z = self._z_low - cfg.ground_drop_m
        tiles = 24
        gx = np.linspace(lo[0], hi[0], tiles + 1)
        gy = np.linspace(lo[1], hi[1], tiles + 1)
        x0, y0 = np.meshgrid(gx[:-1], gy[:-1], indexing="ij")
        x1, y1 = np.meshgrid(gx[1:], gy[1:], indexing="ij")
        x0, y0, x1, y1 = (a.ravel() for a in (x0, y0, x1, y1))
        zz = np.full_like(x0, z)
        ground = _QuadMesh()
        ground.add(
            np.stack([x0, y0, zz], 1),
            np.stack([x1, y0, zz], 1),
            np.stack([x1, y1, zz], 1),
            np.stack([x0, y1, zz], 1),
            (0.0, 0.0, 1.0),
        )
        self._visual_bodies(ground, cfg.ground_colour)

    def _build_cars(self) -> list[int]:
        length, width, height = self.car_size
        half = [0.5 * length, 0.5 * width, 0.5 * height]
        collision = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, **self._cid)
        colours = self.config.car_colours
        bodies = []
        for i in range(self.n_cars):
            visual = pb.createVisualShape(
                pb.GEOM_BOX, halfExtents=half, rgbaColor=list(colours[i % len(colours)]), **self._cid
            )
            mask = _RAY_BIT | _BARRIER_GROUP | sum(_FIRST_CAR_BIT << j for j in range(self.n_cars) if j != i)
            bodies.append(self._static_body(collision, visual, _FIRST_CAR_BIT << i, mask))
        return bodies

    def _park_cars(self) -> None:
        """Put the cars far below and apart from everything until the caller places them."""
        x0 = float(min(self._left[:, 0].min(), self._right[:, 0].min())) - 1000.0
        z = self._z_low - 1000.0
        self._pose = [(x0 - 50.0 * i, 0.0, z, 0.0, 0.0, 0.0) for i in range(self.n_cars)]
        self._sweep_point = [None] * self.n_cars
        self._centre = [(0.0, 0.0, 0.0)] * self.n_cars
        for i, pose in enumerate(self._pose):
            self.set_car_pose(i, *pose, teleport=True)
        self._sweep_point = [None] * self.n_cars

    # ------------------------------------------------------------------------------------- per step

    @property
    def client_id(self) -> int:
        """The pybullet physics client of this world (for direct pybullet queries)."""
        if self._client is None:
            raise RuntimeError("the world is closed")
        return self._client

    def set_car_pose(
        self,
        i: int,
        x: float,
        y: float,
        z: float,
        yaw: float,
        pitch: float = 0.0,
        roll: float = 0.0,
        teleport: bool = False,
    ) -> None:
        """Place car ``i``: ``(x, y, z)`` is the road point under the car's centre.

        The box sits ``ground_clearance_m`` above that point along the car's up axis. Angles follow
        pybullet (``Rz(yaw) Ry(pitch) Rx(roll)``): yaw counter-clockwise from +x; pitch positive
        turns the nose *down*, so a car climbing a grade ``dz/ds = g`` has ``pitch = -atan(g)``;
        roll positive lowers the right side. ``teleport=True`` (episode resets) skips the barrier
        crossing sweep for this move; the first placement after construction is never swept.
        """
        x, y, z, yaw, pitch, roll = float(x), float(y), float(z), float(yaw), float(pitch), float(roll)
        # Half-angle sines/cosines give both the quaternion and (by double-angle identities) the
        # car's up axis, with 6 trig calls instead of 12.
        hcy, hsy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
        hcp, hsp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
        hcr, hsr = math.cos(0.5 * roll), math.sin(0.5 * roll)
        quaternion = (
            hsr * hcp * hcy - hcr * hsp * hsy,
            hcr * hsp * hcy + hsr * hcp * hsy,
            hcr * hcp * hsy - hsr * hsp * hcy,
            hcr * hcp * hcy + hsr * hsp * hsy,
        )
        cy, sy = hcy * hcy - hsy * hsy, 2.0 * hsy * hcy
        cp, sp = hcp * hcp - hsp * hsp, 2.0 * hsp * hcp
        cr, sr = hcr * hcr - hsr * hsr, 2.0 * hsr * hcr
        # Third column of Rz Ry Rx: the car's up axis in the world.
        ux, uy, uz = cy * sp * cr + sy * sr, sy * sp * cr - cy * sr, cp * cr
        lift = self._centre_lift
        centre = (x + lift * ux, y + lift * uy, z + lift * uz)
        pb.resetBasePositionAndOrientation(
            self.car_body_ids[i], centre, quaternion, physicsClientId=self._client
        )
        self._centre[i] = centre
        self._pose[i] = (x, y, z, yaw, pitch, roll)
        lift = self._sweep_lift
        point = (x + lift * ux, y + lift * uy, z + lift * uz)
        self._sweep_from[i] = None if teleport else self._sweep_point[i]
        self._sweep_point[i] = point

    def car_pose(self, i: int) -> tuple[float, float, float, float, float, float]:
        """The last pose given to ``set_car_pose`` for car ``i``: ``(x, y, z, yaw, pitch, roll)``."""
        return self._pose[i]

    def collisions(self) -> Collisions:
        """Which cars touch each other and which touch (or crossed) a barrier, at their current poses."""
        client = self._client
        closest = pb.getClosestPoints
        reach = self._contact_distance
        bodies = self.car_body_ids
        n_cars = self.n_cars
        centres = self._centre
        pairs = []
        for i in range(n_cars):
            xi, yi, zi = centres[i]
            for j in range(i + 1, n_cars):
                # Skip the pybullet call when the bounding spheres are apart (most steps).
                xj, yj, zj = centres[j]
                if (xi - xj) ** 2 + (yi - yj) ** 2 + (zi - zj) ** 2 > self._pair_skip_distance_sq:
                    continue
                if closest(bodies[i], bodies[j], reach, physicsClientId=client):
                    pairs.append((i, j))
        barrier = self.barrier_body_id
        if barrier is None:
            return Collisions(bool(pairs), (False,) * n_cars, tuple(pairs))
        hits = [bool(closest(body, barrier, reach, physicsClientId=client)) for body in bodies]
        if self._sweep_enabled:
            # A wall can only be jumped without touching it in either pose when the move is longer
            # than the wall's thickness plus the car's smallest extent; shorter moves need no ray.
            starts, ends, moved = [], [], []
            for i in range(n_cars):
                start = self._sweep_from[i]
                if hits[i] or start is None:
                    continue
                end = self._sweep_point[i]
                dx, dy, dz = end[0] - start[0], end[1] - start[1], end[2] - start[2]
                if dx * dx + dy * dy + dz * dz > self._sweep_min_sq:
                    starts.append(start)
                    ends.append(end)
                    moved.append(i)
            if moved:
                results = pb.rayTestBatch(
                    starts, ends, collisionFilterMask=_BARRIER_GROUP, physicsClientId=client
                )
                for i, result in zip(moved, results, strict=True):
                    if result[0] >= 0:
                        hits[i] = True
        return Collisions(bool(pairs), tuple(hits), tuple(pairs))

    # ----------------------------------------------------------------------------------------- rays

    def road_height(self, x: float, y: float) -> float | None:
        """Height of the road surface at ``(x, y)`` by a downward ray, or None off the road."""
        top = self._z_high + 100.0
        bottom = self._z_low - 100.0
        (hit,) = pb.rayTestBatch(
            [(x, y, top)], [(x, y, bottom)], collisionFilterMask=_ROAD_GROUP, physicsClientId=self._client
        )
        return None if hit[0] < 0 else float(hit[3][2])

    def ray_distances(
        self,
        origin: Sequence[float] | np.ndarray,
        directions: np.ndarray,
        max_range: float,
        exclude_car: int | None = None,
        hit_road: bool = False,
    ) -> np.ndarray:
        """Distances from ``origin`` (3,) along ``directions`` (K, 3) to barriers and cars.

        Rays that hit nothing within ``max_range`` return ``max_range``. ``exclude_car`` skips that
        car's body (the car the sensor sits on); ``hit_road`` also lets the road surface stop rays.
        """
        dirs = np.asarray(directions, dtype=float)
        if dirs.ndim != 2 or dirs.shape[1] != 3:
            raise ValueError(f"directions must be (K, 3), got shape {dirs.shape}")
        start = np.asarray(origin, dtype=float).reshape(3)
        lengths = np.sqrt(np.einsum("ij,ij->i", dirs, dirs))
        if not np.all(lengths > 0):
            raise ValueError("directions must be non-zero vectors")
        ends = (start + dirs * (max_range / lengths)[:, None]).tolist()
        mask = _BARRIER_GROUP | self._car_mask_all | (_ROAD_GROUP if hit_road else 0)
        if exclude_car is not None:
            mask &= ~(_FIRST_CAR_BIT << exclude_car)
        results = pb.rayTestBatch(
            [start.tolist()] * len(ends), ends, collisionFilterMask=mask, physicsClientId=self._client
        )
        # pybullet reports hitFraction 1.0 for rays that hit nothing.
        return np.fromiter((r[2] for r in results), dtype=float, count=len(results)) * max_range

    # ---------------------------------------------------------------------------------------- camera

    def render(
        self,
        mode: Literal["chase", "birdseye"] = "chase",
        car: int = 0,
        width: int | None = None,
        height: int | None = None,
    ) -> np.ndarray:
        """An ``(height, width, 3)`` uint8 image from pybullet's TinyRenderer following car ``car``."""
        width = width or self.render_size[0]
        height = height or self.render_size[1]
        cam = self.config.camera
        x, y, z, yaw, _, _ = self._pose[car]
        forward = (math.cos(yaw), math.sin(yaw))
        if mode == "chase":
            eye = (
                x - cam.chase_distance_m * forward[0],
                y - cam.chase_distance_m * forward[1],
                z + cam.chase_height_m,
            )
            target = (
                x + cam.chase_look_ahead_m * forward[0],
                y + cam.chase_look_ahead_m * forward[1],
                z + cam.chase_target_height_m,
            )
            up, fov = (0.0, 0.0, 1.0), cam.chase_fov_deg
        elif mode == "birdseye":
            eye, target = (x, y, z + cam.birdseye_altitude_m), (x, y, z)
            up = (forward[0], forward[1], 0.0) if cam.birdseye_heading_up else (0.0, 1.0, 0.0)
            fov = cam.birdseye_fov_deg
        else:
            raise ValueError(f"render mode must be 'chase' or 'birdseye', got {mode!r}")
        view = pb.computeViewMatrix(eye, target, up, physicsClientId=self._client)
        projection = pb.computeProjectionMatrixFOV(
            fov, width / height, cam.near_m, cam.far_m, physicsClientId=self._client
        )
        _, _, rgba, _, _ = pb.getCameraImage(
            width,
            height,
            view,
            projection,
            renderer=pb.ER_TINY_RENDERER,
            flags=pb.ER_NO_SEGMENTATION_MASK,
            lightDirection=list(cam.light_direction),
            shadow=0,
            physicsClientId=self._client,
        )
        image = np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)
        return np.ascontiguousarray(image[:, :, :3])

    # --------------------------------------------------------------------------------------- closing

    def close(self) -> None:
        """Disconnect this world's pybullet client; further calls do nothing."""
        client, self._client = getattr(self, "_client", None), None
        if client is not None:
            # The server may already be gone (e.g. at interpreter shutdown).
            with contextlib.suppress(Exception):
                pb.disconnect(physicsClientId=client)

    def __enter__(self) -> RaceWorld:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def __del__(self) -> None:
        self.close()
