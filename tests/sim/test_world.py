"""Behaviour of the pybullet race world on a small synthetic track (curve, hill, right barrier)."""

from __future__ import annotations

import math

import numpy as np
import pybullet as pb
import pytest

from d2a_core.sim.rotation import euler_to_quaternion
from d2a_core.sim.world import RaceWorld, WorldConfig

HALF_WIDTH = 5.0
BARRIER_GAP = 1.0  # barrier face this far outside the right edge
BARRIER_HEIGHT = 1.0
LEFT_BARRIER_GAP = 2.0  # a short left barrier on the arc, stations LEFT_BARRIER_SPAN
LEFT_BARRIER_SPAN = slice(60, 71)
HILL = 3.0
LENGTH = 200.0
SPACING = 2.0
CAR = (4.6, 1.9, 1.2)


def _synthetic_track():
    """Centreline: 50 m straight, 100 m left arc (radius 80 m), 50 m straight; a 3 m hill over the lap."""
    s = np.arange(0.0, LENGTH + 1e-9, SPACING)
    kappa = np.where((s > 50.0) & (s < 150.0), 1.0 / 80.0, 0.0)
    ds = np.diff(s)
    heading = np.concatenate([[0.0], np.cumsum(0.5 * (kappa[1:] + kappa[:-1]) * ds)])
    mid = 0.5 * (heading[1:] + heading[:-1])
    x = np.concatenate([[0.0], np.cumsum(np.cos(mid) * ds)])
    y = np.concatenate([[0.0], np.cumsum(np.sin(mid) * ds)])
    z = HILL * np.sin(np.pi * s / LENGTH) ** 2
    centre = np.stack([x, y, z], axis=1)
    normal = np.stack([-np.sin(heading), np.cos(heading), np.zeros_like(s)], axis=1)
    return {
        "s": s,
        "centre": centre,
        "normal": normal,
        "heading": heading,
        "grade": HILL * np.pi / LENGTH * np.sin(2 * np.pi * s / LENGTH),
        "left": centre + HALF_WIDTH * normal,
        "right": centre - HALF_WIDTH * normal,
        "barrier": centre - (HALF_WIDTH + BARRIER_GAP) * normal,
        "left_barrier": (centre + (HALF_WIDTH + LEFT_BARRIER_GAP) * normal)[LEFT_BARRIER_SPAN],
    }


@pytest.fixture(scope="module")
def track():
    return _synthetic_track()


@pytest.fixture(scope="module")
def world(track):
    barriers = [(track["barrier"], BARRIER_HEIGHT), (track["left_barrier"], 0.8)]
    with RaceWorld(track["left"], track["right"], barriers, car_size=CAR) as w:
        yield w


def _place(
    world: RaceWorld, track, car: int, index: int, lateral: float = 0.0, yaw_offset: float = 0.0, **kw
):
    """Put ``car`` at track point ``index`` shifted ``lateral`` metres to the left, flat on the road."""
    point = track["centre"][index] + lateral * track["normal"][index]
    kw.setdefault("teleport", True)
    world.set_car_pose(car, *point, track["heading"][index] + yaw_offset, **kw)


def test_cars_overlapping_collide_and_apart_do_not(world, track):
    _place(world, track, 0, 20)
    _place(world, track, 1, 21)  # 2 m ahead: boxes 4.6 m long overlap
    car_car, car_barrier = world.collisions()
    assert car_car and car_barrier == [False, False]
    _place(world, track, 1, 30)  # 20 m ahead
    assert not world.collisions().car_car


def test_side_by_side_cars_collide_only_when_boxes_overlap(world, track):
    width = CAR[1]
    _place(world, track, 0, 60, lateral=0.0)
    _place(world, track, 1, 60, lateral=width + 0.05)
    assert not world.collisions().car_car
    _place(world, track, 1, 60, lateral=width - 0.05)
    report = world.collisions()
    assert report.car_pairs == ((0, 1),)
    assert report.involves(0) and report.involves(1)


@pytest.mark.parametrize("index", [10, 50, 75])  # straight, hill top, arc
def test_car_against_barrier_collides_and_middle_of_road_does_not(world, track, index):
    face = -(HALF_WIDTH + BARRIER_GAP)
    half_width = CAR[1] / 2
    _place(world, track, 1, (index + 30) % len(track["s"]), lateral=2.5)
    _place(world, track, 0, index, lateral=face + half_width - 0.05)
    assert world.collisions().car_barrier == (True, False)
    _place(world, track, 0, index, lateral=face + half_width + 0.05)
    assert world.collisions().car_barrier == (False, False)
    _place(world, track, 0, index, lateral=0.0)
    report = world.collisions()
    assert not report.car_car and report.car_barrier == (False, False)


def test_left_barrier_wall_extends_away_from_the_road(world, track):
    index = 65
    face = HALF_WIDTH + LEFT_BARRIER_GAP
    half_width = CAR[1] / 2
    _place(world, track, 1, 10)
    _place(world, track, 0, index, lateral=face - half_width + 0.05)
    assert world.collisions().car_barrier == (True, False)
    _place(world, track, 0, index, lateral=face - half_width - 0.05)
    assert world.collisions().car_barrier == (False, False)
    origin = track["centre"][index] + np.array([0.0, 0.0, 0.4])
    left = track["normal"][index]
    assert world.ray_distances(origin, left[None], 30.0, exclude_car=0)[0] == pytest.approx(face, abs=0.03)
    # Behind the wall's end the ray passes.
    beyond = track["centre"][75] + np.array([0.0, 0.0, 0.4])
    assert world.ray_distances(beyond, track["normal"][75][None], 30.0, exclude_car=0)[0] == pytest.approx(
        30.0
    )


def test_car_sunk_into_road_reports_no_road_contact(world, track):
    index = 50
    point = track["centre"][index] - np.array([0.0, 0.0, 0.4])  # box bottom 0.25 m below the surface
    world.set_car_pose(0, *point, track["heading"][index], teleport=True)
    _place(world, track, 1, 5)
    client, car, road = world.client_id, world.car_body_ids[0], world.road_body_id
    # The geometry really overlaps ...
    assert min(c[8] for c in pb.getClosestPoints(car, road, 0.0, physicsClientId=client)) < -0.2
    # ... but pybullet's broadphase never pairs the car with the road.
    pb.performCollisionDetection(physicsClientId=client)
    assert all(road not in (c[1], c[2]) for c in pb.getContactPoints(bodyA=car, physicsClientId=client))
    assert not world.collisions().involves(0)


def test_pitch_convention_matches_the_climbing_road(world, track):
    index = 25  # s = 50 m, steepest uphill grade
    grade = track["grade"][index]
    assert grade > 0.04
    clearance = world.config.ground_clearance_m
    client, car, road = world.client_id, world.car_body_ids[0], world.road_body_id
    _place(world, track, 1, 80)
    gaps = {}
    for sign in (+1, -1):
        _place(world, track, 0, index, pitch=-sign * math.atan(grade))
        points = pb.getClosestPoints(car, road, 1.0, physicsClientId=client)
        gaps[sign] = min(c[8] for c in points)
    assert gaps[+1] == pytest.approx(clearance, abs=0.02)  # the documented pitch = -atan(grade)
    assert gaps[-1] < clearance - 0.1  # the opposite sign digs the nose into the hill


def test_orientation_matches_pybullet_euler_convention(world):
    for yaw, pitch, roll in [(0.3, -0.2, 0.1), (-2.5, 0.4, -0.3), (3.0, 0.0, 0.0)]:
        expected = pb.getQuaternionFromEuler([roll, pitch, yaw])
        assert np.allclose(euler_to_quaternion(yaw, pitch, roll), expected, atol=1e-12)
        world.set_car_pose(0, 0.0, 0.0, 0.0, yaw, pitch, roll, teleport=True)
        position, orientation = pb.getBasePositionAndOrientation(
            world.car_body_ids[0], physicsClientId=world.client_id
        )
        up = np.array(pb.getMatrixFromQuaternion(orientation)).reshape(3, 3)[:, 2]
        lift = world.config.ground_clearance_m + CAR[2] / 2
        assert np.allclose(
            position, lift * up, atol=1e-9
        )  # the box stands on its road point along its up axis


def test_downward_rays_inside_the_road_hit_the_track_elevation(world, track):
    left, right = track["left"], track["right"]
    for index in range(0, len(left) - 1, 7):
        for t in (0.05, 0.3, 0.5, 0.95):
            for between in (0.0, 0.5):  # on a station and halfway to the next
                a = right[index] + t * (left[index] - right[index])
                b = right[index + 1] + t * (left[index + 1] - right[index + 1])
                point = a + between * (b - a)
                height = world.road_height(point[0], point[1])
                assert height is not None
                assert height == pytest.approx(point[2], abs=0.02)
    assert max(track["centre"][:, 2]) > 2.9  # the samples above include the hill top


def test_rays_just_outside_the_road_edges_miss_the_road(world, track):
    normal = track["normal"]
    for index in range(1, len(track["s"]) - 1, 5):
        for edge, outward in ((track["left"], normal), (track["right"], -normal)):
            inside = edge[index] - 0.1 * outward[index]
            outside = edge[index] + 0.1 * outward[index]
            assert world.road_height(inside[0], inside[1]) == pytest.approx(edge[index][2], abs=0.02)
            assert world.road_height(outside[0], outside[1]) is None


@pytest.mark.parametrize("index", [10, 50, 75])
def test_sideways_ray_hits_barrier_at_its_offset(world, track, index):
    _place(world, track, 0, index)
    _place(world, track, 1, (index + 40) % len(track["s"]))
    origin = track["centre"][index] + np.array([0.0, 0.0, 0.5])
    right = -track["normal"][index]
    forward = np.array([math.cos(track["heading"][index]), math.sin(track["heading"][index]), 0.0])
    distances = world.ray_distances(origin, np.stack([right, forward, -right]), max_range=30.0, exclude_car=0)
    assert distances[0] == pytest.approx(HALF_WIDTH + BARRIER_GAP, abs=0.03)
    assert distances[2] == pytest.approx(30.0)  # nothing on the left within range
    # From 2 m left of car 0's centre a rightward ray meets car 0's left side unless car 0 is excluded.
    beside = origin + 2.0 * track["normal"][index]
    assert world.ray_distances(beside, right[None], 30.0)[0] == pytest.approx(2.0 - CAR[1] / 2, abs=0.02)
    excluded = world.ray_distances(beside, right[None], 30.0, exclude_car=0)[0]
    assert excluded == pytest.approx(2.0 + HALF_WIDTH + BARRIER_GAP, abs=0.03)


def test_rays_hit_the_other_car_at_its_rear_face(world, track):
    _place(world, track, 0, 10)  # straight section, heading +x, flat pitch
    _place(world, track, 1, 15)  # 10 m ahead
    origin = track["centre"][10] + np.array([0.0, 0.0, world.config.ground_clearance_m + CAR[2] / 2])
    distance = world.ray_distances(origin, np.array([[1.0, 0.0, 0.0]]), 50.0, exclude_car=0)[0]
    assert distance == pytest.approx(10.0 - CAR[0] / 2, abs=0.02)


def test_barrier_crossing_between_poses_is_a_collision(world, track):
    index = 40
    beyond = -(HALF_WIDTH + BARRIER_GAP + world.config.barrier_thickness_m + 3.0)
    _place(world, track, 1, 80)
    _place(world, track, 0, index, lateral=0.0)
    assert world.collisions().car_barrier == (False, False)
    _place(world, track, 0, index + 2, lateral=beyond, teleport=False)  # jumped through the wall
    assert world.collisions().car_barrier == (True, False)
    _place(world, track, 0, index, lateral=0.0)
    _place(world, track, 0, index + 2, lateral=beyond, teleport=True)  # a reset, not a move
    assert world.collisions().car_barrier == (False, False)


def test_render_shows_road_and_cars(world, track):
    _place(world, track, 0, 40)
    _place(world, track, 1, 43, lateral=2.0)
    chase = world.render("chase", car=0)
    assert chase.shape == (84, 84, 3) and chase.dtype == np.uint8
    assert chase.reshape(-1, 3).std(axis=0).mean() > 20.0
    red = (chase[..., 0] > 150) & (chase[..., 1] < 70) & (chase[..., 2] < 70)
    assert red.sum() > 30  # car 0 fills part of the chase view
    grey_road = (np.abs(chase.astype(int) - np.array([77, 77, 82])).max(axis=2) < 30).sum()
    assert grey_road > 500
    top = world.render("birdseye", car=0, width=96, height=64)
    assert top.shape == (64, 96, 3)
    blue = (top[..., 2] > 150) & (top[..., 0] < 70) & (top[..., 1] < 90)
    red = (top[..., 0] > 150) & (top[..., 1] < 70) & (top[..., 2] < 70)
    assert blue.sum() > 0 and red.sum() > 0
    with pytest.raises(ValueError):
        world.render("sideways")


def test_two_worlds_are_independent(track):
    config = WorldConfig(runoff_width_m=0.0, edge_line_width_m=0.0)
    first = RaceWorld(track["left"], track["right"], [(track["barrier"], BARRIER_HEIGHT)], config=config)
    second = RaceWorld(track["left"] + [0, 0, 10.0], track["right"] + [0, 0, 10.0], [], config=config)
    assert first.client_id != second.client_id
    _place(first, track, 0, 20)
    _place(first, track, 1, 21)
    _place(second, track, 0, 20)
    _place(second, track, 1, 40)
    assert first.collisions().car_car and not second.collisions().car_car
    assert second.road_height(*track["centre"][50, :2]) == pytest.approx(
        track["centre"][50, 2] + 10.0, abs=0.02
    )
    first.close()
    first.close()  # closing twice is harmless
    assert not second.collisions().car_car
    assert second.collisions().car_barrier == (False, False)  # this world has no barriers
    assert second.render("birdseye", width=32, height=32).shape == (32, 32, 3)
    second.close()


def test_bad_geometry_is_rejected(track):
    with pytest.raises(ValueError, match="same shape"):
        RaceWorld(track["left"], track["right"][:-1], [])
    with pytest.raises(ValueError, match="height"):
        RaceWorld(track["left"], track["right"], [(track["barrier"], 0.0)])
    with pytest.raises(ValueError, match="n_cars"):
        RaceWorld(track["left"], track["right"], [], n_cars=0)
