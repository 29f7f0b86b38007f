"""Behaviour of the single-track vehicle model: straight-line performance, cornering at and
below the limit, grade, integration accuracy and low-speed handling."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from d2a_core.sim.tyres import TyreConfig, ellipse_factor, lateral_mu, load_scaled_mu, peak_slip_angle
from d2a_core.sim.vehicle import Vehicle as _Vehicle
from d2a_core.sim.vehicle import VehicleConfig, VehicleState

DT = 0.1
G = 9.81


def raw_config(**overrides) -> VehicleConfig:
    """A car whose steer command maps to a fixed road-wheel angle at every speed, so tyre tests
    can ask for a given angle; speed-sensitive steering has tests of its own."""
    return VehicleConfig(steer_lock_lateral_g=None, **overrides)


def Vehicle(config: VehicleConfig | None = None) -> _Vehicle:  # noqa: N802 - stands in for the class
    return _Vehicle(config if config is not None else raw_config())


def hold_speed(state: VehicleState, target: float) -> float:
    """Proportional throttle/brake that keeps the speed near ``target`` (a steady driver)."""
    return max(-1.0, min(1.0, 0.5 * (target - state.speed) + 0.1))


def settle_in_corner(
    vehicle: Vehicle, steer: float, speed: float, seconds: float = 5.0
) -> VehicleState:
    """Start at ``speed`` and hold it with constant ``steer`` until the cornering is steady."""
    vehicle.reset(0.0, 0.0, 0.0, speed)
    for _ in range(round(seconds / DT)):
        vehicle.step(steer, hold_speed(vehicle.state, speed))
    return vehicle.state.copy()


def run_extremes(
    vehicle: Vehicle, steer: float, accel: float | None, seconds: float = 3.0, hold: float = 0.0
) -> tuple[float, float]:
    """Max |sideslip| (deg) and |yaw rate| while moving faster than 5 m/s over ``seconds``.

    ``accel`` is a constant command, or None to keep holding the speed ``hold``.
    """
    max_beta = 0.0
    max_rate = 0.0
    for _ in range(round(seconds / DT)):
        command = hold_speed(vehicle.state, hold) if accel is None else accel
        s = vehicle.step(steer, command)
        if s.speed > 5.0:
            max_beta = max(max_beta, abs(math.degrees(s.sideslip)))
            max_rate = max(max_rate, abs(s.yaw_rate))
    return max_beta, max_rate


def fitted_radius(xs: list[float], ys: list[float]) -> float:
    """Least-squares circle through the points (algebraic fit)."""
    x = np.asarray(xs)
    y = np.asarray(ys)
    a = np.column_stack([x, y, np.ones_like(x)])
    b = x * x + y * y
    cx2, cy2, c = np.linalg.lstsq(a, b, rcond=None)[0]
    cx, cy = cx2 / 2.0, cy2 / 2.0
    return float(math.sqrt(c + cx * cx + cy * cy))


# --- straight line -----------------------------------------------------------------------------


def test_full_throttle_from_rest_accelerates_to_plausible_top_speed():
    vehicle = Vehicle()
    vehicle.reset(0.0, 0.0, 0.0, 0.0)
    speeds = [vehicle.step(0.0, 1.0).vx for _ in range(900)]
    time_to_100_kmh = (next(i for i, v in enumerate(speeds) if v >= 100 / 3.6) + 1) * DT
    assert 2.0 < time_to_100_kmh < 6.0
    assert all(b >= a - 1e-9 for a, b in zip(speeds, speeds[1:])), "speed must rise monotonically"
    top = speeds[-1]
    assert 40.0 < top < 75.0
    assert top - speeds[-100] < 0.5, "top speed has settled (drag balances the power)"
    assert abs(vehicle.state.y) < 1e-9 and abs(vehicle.state.yaw) < 1e-12


def test_power_limit_sets_acceleration_at_speed():
    config = raw_config()
    vehicle = Vehicle(config)
    speed = 40.0
    vehicle.reset(0.0, 0.0, 0.0, speed)
    s = vehicle.step(0.0, 1.0, dt=0.01)
    drag = 0.5 * config.air_density_kg_m3 * config.drag_area_m2 * speed**2
    rolling = config.rolling_resistance * config.mass_kg * G
    expected = (config.engine_power_w / speed - drag - rolling) / config.mass_kg
    assert s.ax == pytest.approx(expected, rel=0.03)


def test_hard_braking_from_40_stops_in_plausible_distance_and_never_reverses():
    vehicle = Vehicle()
    vehicle.reset(0.0, 0.0, 0.0, 40.0)
    xs = [0.0]
    for _ in range(80):
        s = vehicle.step(0.0, -1.0)
        assert s.vx >= 0.0
        xs.append(s.x)
    assert vehicle.state.vx == 0.0 and vehicle.state.speed == 0.0
    stop_distance = xs[-1]
    assert 35.0 < stop_distance < 80.0
    # mean deceleration of the order of mu * g
    assert 0.9 * G < 40.0**2 / (2.0 * stop_distance) < 1.7 * G
    assert all(b >= a for a, b in zip(xs, xs[1:])), "the car never moves backwards"


def test_brakes_hold_on_a_slope_and_release_lets_the_car_roll_back():
    vehicle = Vehicle()
    vehicle.reset(0.0, 0.0, 0.0, 0.0)
    for _ in range(30):
        s = vehicle.step(0.0, -1.0, grade=0.15)
    assert s.vx == 0.0 and s.x == 0.0
    for _ in range(10):
        s = vehicle.step(0.0, 0.0, grade=0.15)
    assert s.vx < -0.5, "without brakes gravity rolls the car back down"


def test_coasting_decelerates_by_drag_and_rolling_resistance_without_spinning():
    config = raw_config()
    vehicle = Vehicle(config)
    speed = 40.0
    vehicle.reset(0.0, 0.0, 0.0, speed)
    s = vehicle.step(0.0, 0.0, dt=0.01)
    drag = 0.5 * config.air_density_kg_m3 * config.drag_area_m2 * speed**2
    rolling = config.rolling_resistance * config.mass_kg * G
    assert (speed - s.vx) / 0.01 == pytest.approx((drag + rolling) / config.mass_kg, rel=0.02)
    previous = s.speed
    for _ in range(100):
        s = vehicle.step(0.0, 0.0)
        assert s.speed < previous
        previous = s.speed
    assert abs(s.sideslip) < 1e-9 and abs(s.yaw_rate) < 1e-9
    # coasting through a gentle bend stays composed too
    vehicle.reset(0.0, 0.0, 0.0, 35.0)
    max_beta, _ = run_extremes(vehicle, 0.06, 0.0, seconds=8.0)
    assert max_beta < 3.0


# --- grade -------------------------------------------------------------------------------------


def _distance_after(grade: float, seconds: float = 10.0) -> tuple[float, float]:
    vehicle = Vehicle()
    vehicle.reset(0.0, 0.0, 0.0, 20.0)
    for _ in range(round(seconds / DT)):
        s = vehicle.step(0.0, 0.5, grade=grade)
    return s.x, s.speed


def test_climb_slows_the_car_and_descent_speeds_it_up():
    flat_distance, flat_speed = _distance_after(0.0)
    climb_distance, climb_speed = _distance_after(0.08)
    descent_distance, descent_speed = _distance_after(-0.08)
    assert climb_distance < 0.95 * flat_distance and climb_speed < flat_speed - 3.0
    assert descent_distance > 1.05 * flat_distance and descent_speed > flat_speed + 3.0


def test_grade_force_is_the_slope_component_of_gravity():
    rates = {}
    for grade in (0.0, 0.08):
        vehicle = Vehicle()
        vehicle.reset(0.0, 0.0, 0.0, 20.0)
        s = vehicle.step(0.0, 0.3, grade=grade, dt=0.01)
        rates[grade] = (s.vx - 20.0) / 0.01
    expected = G * 0.08 / math.sqrt(1.0 + 0.08**2)
    assert rates[0.0] - rates[0.08] == pytest.approx(expected, rel=0.03)


# --- cornering ---------------------------------------------------------------------------------


def test_steady_corner_at_sane_speed_is_stable_with_yaw_rate_speed_over_radius():
    config = raw_config()
    vehicle = Vehicle(config)
    steer = 0.3
    speed = 15.0
    settle_in_corner(vehicle, steer, speed, seconds=6.0)
    xs, ys, betas, rates, speeds = [], [], [], [], []
    for _ in range(40):
        s = vehicle.step(steer, hold_speed(vehicle.state, speed))
        xs.append(s.x)
        ys.append(s.y)
        betas.append(abs(s.sideslip))
        rates.append(s.yaw_rate)
        speeds.append(s.speed)
    radius = fitted_radius(xs, ys)
    assert max(betas) < math.radians(5.0)
    assert np.mean(rates) == pytest.approx(np.mean(speeds) / radius, rel=0.02)
    assert max(rates) - min(rates) < 0.01, "steady: the yaw rate does not oscillate"
    # mild understeer: a bit wider than the kinematic (no-slip) radius, not wildly so
    kinematic = config.wheelbase_m / math.tan(steer * config.max_steer_rad)
    assert kinematic < radius < 1.4 * kinematic
    assert 0.5 * G < np.mean(speeds) ** 2 / radius < 1.0 * G


def test_steady_corner_forces_are_the_magic_formula_at_the_reported_slip_angles():
    """Yaw balance puts lf / L of the lateral force on the rear axle; the tyre curve must supply it."""
    config = raw_config()
    vehicle = Vehicle(config)
    s = settle_in_corner(vehicle, 0.3, 15.0, seconds=6.0)
    wheelbase = config.wheelbase_m
    rear_load = config.mass_kg * G * config.cog_to_front_axle_m / wheelbase
    rear_force_needed = config.mass_kg * s.ay * config.cog_to_front_axle_m / wheelbase
    tyre = config.rear_tyre
    mu_scale = load_scaled_mu(tyre, rear_load, rear_load) / tyre.d_peak_mu
    rear_force = rear_load * mu_scale * lateral_mu(s.slip_angle_rear, tyre)
    assert s.slip_angle_rear > 0.0 and s.slip_angle_front > 0.0, "a left turn loads both axles left"
    assert rear_force == pytest.approx(rear_force_needed, rel=0.01)
    assert s.ay == pytest.approx(s.speed * s.yaw_rate, rel=0.01)


def test_steering_left_and_right_mirror_each_other():
    paths = {}
    for sign in (1.0, -1.0):
        vehicle = Vehicle()
        vehicle.reset(0.0, 0.0, 0.0, 20.0)
        for i in range(50):
            s = vehicle.step(sign * 0.4 * math.sin(0.5 * i), 0.4 if i < 30 else -0.5)
        paths[sign] = (s.x, s.y, s.yaw, s.yaw_rate, s.slip_angle_front)
    left, right = paths[1.0], paths[-1.0]
    assert left[0] == pytest.approx(right[0], abs=1e-9)
    for a, b in zip(left[1:], right[1:]):
        assert a == pytest.approx(-b, abs=1e-9)
    assert abs(left[1]) > 1.0


# Slow corner (road-wheel angle 0.21 rad, radius ~15 m) at ~1.45 g: power oversteer territory.
SLOW_CORNER = (0.6, 15.5)
# Fast corner (0.0875 rad, radius ~70 m) at ~1.45 g: braking shifts load off the rear.
FAST_CORNER = (0.25, 32.0)


@pytest.mark.parametrize("corner", [SLOW_CORNER, FAST_CORNER])
def test_corner_at_the_limit_held_at_constant_speed_does_not_spin(corner):
    steer, speed = corner
    vehicle = Vehicle()
    entry = settle_in_corner(vehicle, steer, speed)
    assert entry.speed * entry.yaw_rate > 1.35 * G, "this corner is taken at the limit"
    max_beta, max_rate = run_extremes(vehicle, steer, None, seconds=3.0, hold=speed)
    assert max_beta < 4.0
    assert max_rate < 1.02 * abs(entry.yaw_rate)


def test_full_throttle_at_the_limit_mid_corner_spins():
    steer, speed = SLOW_CORNER
    vehicle = Vehicle()
    entry = settle_in_corner(vehicle, steer, speed)
    max_beta, max_rate = run_extremes(vehicle, steer, 1.0, seconds=3.0)
    assert max_beta > 90.0, "the rear steps out: heading turns away from the velocity"
    assert max_rate > 2.0 * abs(entry.yaw_rate)


def test_hard_braking_at_the_limit_mid_corner_spins():
    steer, speed = FAST_CORNER
    vehicle = Vehicle()
    entry = settle_in_corner(vehicle, steer, speed)
    max_beta, max_rate = run_extremes(vehicle, steer, -0.8, seconds=3.0)
    assert max_beta > 60.0
    assert max_rate > 2.5 * abs(entry.yaw_rate)


def test_full_braking_at_the_limit_mid_corner_ends_in_a_sideways_slide():
    """Both axles near lock-up: less yaw than a spin, but the car slides off its heading."""
    steer, speed = FAST_CORNER
    vehicle = Vehicle()
    entry = settle_in_corner(vehicle, steer, speed)
    max_beta, max_rate = run_extremes(vehicle, steer, -1.0, seconds=3.0)
    assert max_beta > 60.0
    assert max_rate > 1.5 * abs(entry.yaw_rate)


@pytest.mark.parametrize("corner", [SLOW_CORNER, FAST_CORNER, (0.15, 40.0)])
def test_combined_acceleration_stays_inside_the_friction_circle(corner):
    """Braking or driving at the limit trades lateral for longitudinal grip (friction ellipse)."""
    steer, speed = corner
    tyres = (VehicleConfig().front_tyre, VehicleConfig().rear_tyre)
    peak = max(lateral_mu(peak_slip_angle(t), t) for t in tyres)
    for accel in (-1.0, -0.8, 1.0):
        vehicle = Vehicle()
        settle_in_corner(vehicle, steer, speed)
        highest = 0.0
        for _ in range(30):
            s = vehicle.step(steer, accel)
            if s.speed > 5.0:
                highest = max(highest, math.hypot(s.ax, s.ay))
        assert 1.2 * G < highest < 1.05 * peak * G


def test_braking_in_a_straight_line_damps_a_yaw_disturbance():
    vehicle = Vehicle()
    vehicle.reset(0.0, 0.0, 0.0, 60.0)
    vehicle.state.yaw_rate = 0.1
    max_beta, _ = run_extremes(vehicle, 0.0, -1.0, seconds=3.0)
    assert max_beta < 1.0
    assert abs(vehicle.state.yaw_rate) < 0.02


# --- integration -------------------------------------------------------------------------------


def _slalom_path(substeps: int) -> list[tuple[float, float]]:
    vehicle = Vehicle(raw_config(substeps=substeps))
    vehicle.reset(0.0, 0.0, 0.0, 20.0)
    path = []
    for i in range(60):
        accel = 0.5 if i < 30 else (-0.4 if i < 40 else 0.3)
        s = vehicle.step(0.4 * math.sin(0.6 * i * DT), accel)
        path.append((s.x, s.y))
    return path


def _max_error_relative_to_distance(path, reference) -> float:
    distance = sum(math.dist(a, b) for a, b in zip(reference, reference[1:]))
    return max(math.dist(a, b) for a, b in zip(path, reference)) / distance


def test_default_substeps_agree_with_four_times_finer_integration():
    default = VehicleConfig().substeps
    reference = _slalom_path(4 * default)
    error = _max_error_relative_to_distance(_slalom_path(default), reference)
    assert error < 0.01
    # the comparison is sensitive: a single Euler step per control step is clearly off
    assert _max_error_relative_to_distance(_slalom_path(1), reference) > 2.0 * error


# --- low speed and robustness ------------------------------------------------------------------


def test_low_speed_full_lock_follows_the_kinematic_circle():
    config = raw_config()
    vehicle = Vehicle(config)
    vehicle.reset(0.0, 0.0, 0.0, 0.0)
    for _ in range(40):
        s = vehicle.step(1.0, 0.05 if vehicle.state.speed < 1.5 else 0.0)
    delta = config.max_steer_rad
    cog_radius = math.hypot(config.cog_to_rear_axle_m, config.wheelbase_m / math.tan(delta))
    assert s.speed / s.yaw_rate == pytest.approx(cog_radius, rel=0.02)
    assert s.slip_angle_front == pytest.approx(0.0, abs=1e-6)
    assert s.slip_angle_rear == pytest.approx(0.0, abs=1e-6)


def test_standstill_with_steering_stays_put():
    vehicle = Vehicle()
    vehicle.reset(3.0, -2.0, 1.0, 0.0)
    for _ in range(20):
        s = vehicle.step(1.0, 0.0)
    assert (s.x, s.y, s.yaw, s.speed, s.yaw_rate) == (3.0, -2.0, 1.0, 0.0, 0.0)
    assert s.steer == pytest.approx(VehicleConfig().max_steer_rad)


def test_steering_is_rate_limited():
    config = raw_config()
    vehicle = Vehicle(config)
    vehicle.reset(0.0, 0.0, 0.0, 10.0)
    s = vehicle.step(1.0, 0.0)
    assert s.steer == pytest.approx(config.max_steer_rate_rad_s * DT)


def test_spin_recovers_to_rest_without_numerical_trouble():
    vehicle = Vehicle()
    settle_in_corner(vehicle, *SLOW_CORNER)
    for _ in range(30):
        vehicle.step(SLOW_CORNER[0], 1.0)
    for _ in range(100):
        s = vehicle.step(0.0, -1.0)
        assert all(math.isfinite(v) for v in (s.x, s.y, s.yaw, s.vx, s.vy, s.yaw_rate))
        assert -math.pi <= s.yaw <= math.pi
    assert s.speed == 0.0


def test_commands_are_clipped_and_nan_is_rejected():
    a, b = Vehicle(), Vehicle()
    a.reset(0.0, 0.0, 0.0, 10.0)
    b.reset(0.0, 0.0, 0.0, 10.0)
    sa = a.step(5.0, 3.0)
    sb = b.step(1.0, 1.0)
    assert (sa.x, sa.y, sa.vx, sa.steer) == (sb.x, sb.y, sb.vx, sb.steer)
    with pytest.raises(ValueError):
        a.step(float("nan"), 0.0)
    with pytest.raises(ValueError):
        a.step(0.0, 0.0, dt=0.0)


# --- tyres and config --------------------------------------------------------------------------


def test_tyre_curve_peaks_at_d_and_falls_off_beyond():
    tyre = VehicleConfig().rear_tyre
    peak = peak_slip_angle(tyre)
    assert math.radians(3.0) < peak < math.radians(12.0)
    assert lateral_mu(peak, tyre) == pytest.approx(tyre.d_peak_mu, rel=1e-6)
    assert lateral_mu(-0.05, tyre) == pytest.approx(-lateral_mu(0.05, tyre))
    assert lateral_mu(0.6, tyre) < 0.95 * tyre.d_peak_mu, "sliding grip is below peak grip"
    assert ellipse_factor(0.0, 100.0) == 1.0
    assert ellipse_factor(60.0, 100.0) == pytest.approx(0.8)
    assert ellipse_factor(120.0, 100.0) == 0.0
    loaded = TyreConfig(load_sensitivity=0.3)
    assert load_scaled_mu(loaded, 1.2, 1.0) < loaded.d_peak_mu < load_scaled_mu(loaded, 0.8, 1.0)


def test_config_rejects_unknown_and_inconsistent_values_and_merges_partial_tyres():
    with pytest.raises(ValidationError):
        VehicleConfig(wings=True)
    with pytest.raises(ValidationError):
        VehicleConfig(mass_kg=-1.0)
    with pytest.raises(ValidationError):
        VehicleConfig(blend_speed_low_m_s=6.0, blend_speed_high_m_s=5.0)
    config = VehicleConfig.model_validate({"rear_tyre": {"b_stiffness": 11.0}})
    default = VehicleConfig()
    assert config.rear_tyre.b_stiffness == 11.0
    assert config.rear_tyre.d_peak_mu == default.rear_tyre.d_peak_mu
    assert config.front_tyre == default.front_tyre


def test_steer_lock_shrinks_with_speed_but_still_allows_driving_past_the_grip():
    config = VehicleConfig()
    assert config.steer_lock_rad(0.0) == config.max_steer_rad
    assert config.steer_lock_rad(8.0) == config.max_steer_rad
    locks = [config.steer_lock_rad(v) for v in (20.0, 30.0, 40.0, 60.0)]
    assert all(a > b for a, b in zip(locks, locks[1:]))
    # full lock asks about steer_lock_lateral_g of lateral acceleration (kinematic estimate)
    v = 40.0
    assert v * v * math.tan(config.steer_lock_rad(v)) / config.wheelbase_m == pytest.approx(3.0 * G, rel=1e-6)
    assert VehicleConfig(steer_lock_lateral_g=None).steer_lock_rad(v) == config.max_steer_rad


@pytest.mark.parametrize("speed, accel", [(25.0, 1.0), (40.0, -0.5)], ids=["power-oversteer", "brake-in-turn"])
def test_full_lock_at_speed_can_still_spin_the_car(speed, accel):
    """Speed-sensitive steering keeps the input range usable, not the car safe."""
    vehicle = _Vehicle(VehicleConfig())
    vehicle.reset(0.0, 0.0, 0.0, speed)
    max_beta = 0.0
    for _ in range(30):
        s = vehicle.step(1.0, accel)
        max_beta = max(max_beta, abs(math.degrees(s.sideslip)))
    assert max_beta > 60.0


def test_small_commands_at_speed_stay_within_grip():
    """A policy's exploration noise (about 0.1 of full scale) does not spin the car at 40 m/s."""
    vehicle = _Vehicle(VehicleConfig())
    vehicle.reset(0.0, 0.0, 0.0, 40.0)
    for i in range(50):
        s = vehicle.step(0.1 * (-1) ** (i // 3), 0.5)
        assert abs(math.degrees(s.sideslip)) < 3.0
