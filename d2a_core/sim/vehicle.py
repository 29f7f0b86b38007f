"""Rear-wheel-drive single-track (dynamic bicycle) vehicle model.

Forces: Pacejka lateral tyre forces per axle combined with the longitudinal force through a
friction ellipse, longitudinal load transfer, a power-limited drive on the rear axle, brakes with a
front/rear bias, aero drag, rolling resistance and the grade force of the road. Integrated with
``substeps`` substeps per control step: velocities by explicit Euler from the substep's start
state (load transfer taken from the previous substep, which avoids an algebraic loop), the pose by
the trapezoidal rule on the old and new velocities. Below a blending speed the lateral and yaw
states are blended toward the kinematic bicycle, where the slip-angle dynamics would be too stiff
for explicit substeps (and the slip angles ill-defined at standstill).

The hot path is scalar Python with ``math`` on local variables, about 1.5 us per substep (numpy or
torch calls would cost more than the whole step). ``Vehicle`` reads its config once, when built.

Frames: world ``x, y`` (m) and ``yaw`` (rad, counter-clockwise from +x); velocities ``vx``
(forward) and ``vy`` (left) in the body frame at the centre of gravity; ``yaw_rate`` positive
counter-clockwise; steer angle positive to the left.
"""

from __future__ import annotations

import math
from typing import Optional

from pydantic import Field, ValidationInfo, field_validator, model_validator

from d2a_core.config.section import Section

from d2a_core.sim.tyres import TyreConfig

_TWO_PI = 2.0 * math.pi


def _front_tyre() -> TyreConfig:
    return TyreConfig(
        b_stiffness=10.0, c_shape=1.9, d_peak_mu=1.55, e_curvature=0.9, load_sensitivity=0.3
    )


def _rear_tyre() -> TyreConfig:
    return TyreConfig(
        b_stiffness=13.0, c_shape=1.9, d_peak_mu=1.65, e_curvature=0.9, load_sensitivity=0.3
    )


class VehicleConfig(Section):
    """Physical parameters of the car; defaults describe a plausible rear-wheel-drive race car."""


    mass_kg: float = Field(1250.0, gt=0)
    yaw_inertia_kg_m2: float = Field(1800.0, gt=0)
    cog_to_front_axle_m: float = Field(1.43, gt=0, description="lf; 45/55 front/rear static load")
    cog_to_rear_axle_m: float = Field(1.17, gt=0, description="lr")
    cog_height_m: float = Field(0.35, ge=0)
    front_tyre: TyreConfig = Field(default_factory=_front_tyre)
    rear_tyre: TyreConfig = Field(default_factory=_rear_tyre)
    max_steer_rad: float = Field(0.35, gt=0, lt=1.2, description="road-wheel angle at steer command 1")
    max_steer_rate_rad_s: float = Field(1.5, gt=0, description="slew limit of the road-wheel angle")
    steer_lock_lateral_g: Optional[float] = Field(
        3.0,
        gt=0,
        description="speed-sensitive steering: at speed, steer command 1 asks at most this lateral "
        "acceleration (kinematic estimate, in g) instead of max_steer_rad; null disables",
    )
    engine_power_w: float = Field(250_000.0, gt=0, description="drive force is capped by power / speed")
    max_drive_force_n: float = Field(
        10_000.0, gt=0, description="drive force cap at low speed (torque / traction limit)"
    )
    max_brake_force_n: float = Field(16_000.0, gt=0, description="total brake force at brake command 1")
    brake_bias_front: float = Field(
        0.58, ge=0, le=1, description="share of the brake force on the front axle"
    )
    drag_area_m2: float = Field(1.5, ge=0, description="Cd * A")
    air_density_kg_m3: float = Field(1.225, ge=0)
    rolling_resistance: float = Field(0.015, ge=0, description="rolling resistance coefficient")
    gravity_m_s2: float = Field(9.81, gt=0)
    substeps: int = Field(10, ge=1, le=1000, description="Euler substeps per control step")
    blend_speed_low_m_s: float = Field(
        2.0, ge=0, description="below: purely kinematic lateral/yaw states"
    )
    blend_speed_high_m_s: float = Field(5.0, gt=0, description="above: purely dynamic model")
    kinematic_relaxation_s: float = Field(
        0.05, gt=0, description="time constant pulling vy and yaw rate to kinematic values at low speed"
    )
    standstill_speed_m_s: float = Field(
        0.05,
        ge=0,
        description="below: lateral and yaw motion snap to kinematic, reported sideslip is zero",
    )
    min_axle_load_fraction: float = Field(
        0.05, gt=0, lt=0.5, description="floor of an axle's normal load, as a share of the weight"
    )

    @field_validator("front_tyre", "rear_tyre", mode="before")
    @classmethod
    def _partial_tyre_over_axle_defaults(cls, value: object, info: ValidationInfo) -> object:
        # A partial override such as {"b_stiffness": 11} changes that coefficient of this axle's
        # tyre, not every other coefficient back to the generic TyreConfig defaults.
        if isinstance(value, dict):
            defaults = _front_tyre() if info.field_name == "front_tyre" else _rear_tyre()
            return {**defaults.model_dump(), **value}
        return value

    @model_validator(mode="after")
    def _blend_band_is_ordered(self) -> "VehicleConfig":
        if self.blend_speed_high_m_s <= self.blend_speed_low_m_s:
            raise ValueError("blend_speed_high_m_s must be greater than blend_speed_low_m_s")
        return self

    @property
    def wheelbase_m(self) -> float:
        """Distance between the axles."""
        return self.cog_to_front_axle_m + self.cog_to_rear_axle_m

    def steer_lock_rad(self, speed_m_s: float) -> float:
        """Road-wheel angle at steer command 1 when driving at `speed_m_s`.

        Like CARLA's steering curve or a racing wheel's speed-sensitive ratio: a fixed lock of
        0.35 rad at 40 m/s asks for ~15 g, so every command above a few percent would spin the car
        and no driver (or policy with exploration noise) could use the input range. The limit
        still allows about twice the tyres' grip, so the car can be driven past it and spun.
        """
        if self.steer_lock_lateral_g is None or speed_m_s <= 0.0:
            return self.max_steer_rad
        grip_angle = math.atan(self.wheelbase_m * self.steer_lock_lateral_g * self.gravity_m_s2 / (speed_m_s * speed_m_s))
        return min(self.max_steer_rad, grip_angle)


class VehicleState:
    """Mutable state of one car; the derived fields are refreshed at the end of every ``step``.

    Integrated: ``x, y, yaw, vx, vy, yaw_rate, steer``. Derived: ``slip_angle_front`` and
    ``slip_angle_rear`` (rad, sign convention ``delta - atan((vy + lf r) / vx)`` so a positive
    angle gives a force to the left; faded to zero below the low-speed blend band), ``ax`` and
    ``ay`` (m/s^2, what an accelerometer on the car reads, positive forward and left), ``speed``
    (m/s, magnitude of the velocity) and ``sideslip`` (rad, ``atan2(vy, vx)``: angle from the
    heading to the velocity, zero at rest). ``yaw`` is kept in [-pi, pi]. ``tyre_ax`` is internal
    integration state (ground longitudinal force per unit mass of the last substep, which sets
    the load transfer of the next one).
    """

    __slots__ = (
        "x",
        "y",
        "yaw",
        "vx",
        "vy",
        "yaw_rate",
        "steer",
        "slip_angle_front",
        "slip_angle_rear",
        "ax",
        "ay",
        "speed",
        "sideslip",
        "tyre_ax",
    )

    def __init__(self, x: float = 0.0, y: float = 0.0, yaw: float = 0.0, speed: float = 0.0) -> None:
        self.x = float(x)
        self.y = float(y)
        self.yaw = math.remainder(float(yaw), _TWO_PI)
        self.vx = float(speed)
        self.vy = 0.0
        self.yaw_rate = 0.0
        self.steer = 0.0
        self.slip_angle_front = 0.0
        self.slip_angle_rear = 0.0
        self.ax = 0.0
        self.ay = 0.0
        self.speed = abs(float(speed))
        self.sideslip = 0.0 if speed >= 0.0 else math.pi
        self.tyre_ax = 0.0

    def copy(self) -> "VehicleState":
        """An independent copy of the state."""
        other = VehicleState.__new__(VehicleState)
        for name in VehicleState.__slots__:
            setattr(other, name, getattr(self, name))
        return other


class Vehicle:
    """One car: holds its configuration and state and advances them by control steps."""

    def __init__(self, config: VehicleConfig | None = None) -> None:
        self.config = config if config is not None else VehicleConfig()
        self.state = VehicleState()
        self._cache_constants()

    def _cache_constants(self) -> None:
        c = self.config
        wheelbase = c.wheelbase_m
        weight = c.mass_kg * c.gravity_m_s2
        static_front = weight * c.cog_to_rear_axle_m / wheelbase
        static_rear = weight * c.cog_to_front_axle_m / wheelbase
        grip = max(c.front_tyre.d_peak_mu, c.rear_tyre.d_peak_mu)
        self._k = (
            c.mass_kg,
            1.0 / c.mass_kg,
            1.0 / c.yaw_inertia_kg_m2,
            c.cog_to_front_axle_m,
            c.cog_to_rear_axle_m,
            c.cog_to_rear_axle_m / wheelbase,  # static front load share
            c.cog_to_front_axle_m / wheelbase,  # static rear load share
            c.mass_kg * c.cog_height_m / wheelbase,  # load transfer per unit acceleration
            1.0 / wheelbase,
            c.front_tyre.b_stiffness,
            c.front_tyre.c_shape,
            c.front_tyre.e_curvature,
            # Load-sensitive peak friction, mu = mu0 - slope * Fz (see tyres.load_scaled_mu).
            c.front_tyre.d_peak_mu * (1.0 + c.front_tyre.load_sensitivity),
            c.front_tyre.d_peak_mu * c.front_tyre.load_sensitivity / static_front,
            0.1 * c.front_tyre.d_peak_mu,
            c.rear_tyre.b_stiffness,
            c.rear_tyre.c_shape,
            c.rear_tyre.e_curvature,
            c.rear_tyre.d_peak_mu * (1.0 + c.rear_tyre.load_sensitivity),
            c.rear_tyre.d_peak_mu * c.rear_tyre.load_sensitivity / static_rear,
            0.1 * c.rear_tyre.d_peak_mu,
            c.max_steer_rad,
            c.max_steer_rate_rad_s,
            c.engine_power_w,
            c.max_drive_force_n,
            c.max_brake_force_n * c.brake_bias_front,
            c.max_brake_force_n * (1.0 - c.brake_bias_front),
            0.5 * c.air_density_kg_m3 * c.drag_area_m2,
            c.rolling_resistance,
            c.gravity_m_s2,
            c.substeps,
            c.blend_speed_low_m_s,
            1.0 / (c.blend_speed_high_m_s - c.blend_speed_low_m_s),
            1.0 / c.kinematic_relaxation_s,
            # Friction bounds on the kinematic relaxation: the most the tyres could deliver.
            grip * c.gravity_m_s2,
            grip * weight * max(c.cog_to_front_axle_m, c.cog_to_rear_axle_m) / c.yaw_inertia_kg_m2,
            c.min_axle_load_fraction,
            c.standstill_speed_m_s,
        )

    def reset(self, x: float, y: float, yaw: float, speed: float = 0.0) -> VehicleState:
        """Place the car at ``(x, y)`` heading ``yaw`` and moving straight ahead at ``speed``."""
        self.state = VehicleState(x, y, yaw, speed)
        return self.state

    def step(
        self, steer_cmd: float, accel_cmd: float, grade: float = 0.0, dt: float = 0.1
    ) -> VehicleState:
        """Advance the car by one control step of ``dt`` seconds and return its (mutated) state.

        ``steer_cmd`` in [-1, 1] (positive left) sets the target road-wheel angle, reached under
        the steering rate limit. ``accel_cmd`` in [-1, 1]: positive is the share of the available
        rear drive force (capped by torque and power), negative the share of the brake force.
        ``grade`` is the road's slope dz/ds along the car's heading (positive uphill). Commands
        outside [-1, 1] are clipped; NaN inputs or a non-positive ``dt`` raise ``ValueError``.
        """
        (
            mass,
            inv_mass,
            inv_iz,
            lf,
            lr,
            front_share,
            rear_share,
            transfer_gain,
            inv_wheelbase,
            bf,
            cf,
            ef,
            mu0_f,
            mu_slope_f,
            mu_min_f,
            br,
            cr,
            er,
            mu0_r,
            mu_slope_r,
            mu_min_r,
            max_steer,
            steer_rate,
            power,
            max_drive,
            max_brake_front,
            max_brake_rear,
            drag_k,
            c_rr,
            g,
            substeps,
            blend_low,
            inv_blend_band,
            inv_kin_tau,
            max_lat_acc,
            max_yaw_acc,
            min_load_frac,
            standstill,
        ) = self._k
        atan = math.atan
        atan2 = math.atan2
        sin = math.sin
        cos = math.cos
        sqrt = math.sqrt

        if steer_cmd != steer_cmd or accel_cmd != accel_cmd or grade != grade or not dt > 0.0:
            raise ValueError(
                f"invalid vehicle input: steer={steer_cmd} accel={accel_cmd} grade={grade} dt={dt}"
            )
        steer_cmd = 1.0 if steer_cmd > 1.0 else (-1.0 if steer_cmd < -1.0 else float(steer_cmd))
        accel_cmd = 1.0 if accel_cmd > 1.0 else (-1.0 if accel_cmd < -1.0 else float(accel_cmd))
        h = dt / substeps
        steer_target = steer_cmd * self.config.steer_lock_rad(self.state.speed)
        max_steer_change = steer_rate * h
        # Relaxing faster than one substep would overshoot (explicit Euler).
        kin_rate = inv_kin_tau if inv_kin_tau * h < 1.0 else 1.0 / h

        # The grade is fixed over the control step: gravity's split into normal load and a force
        # along the heading.
        inv_norm = 1.0 / sqrt(1.0 + grade * grade)
        weight = mass * g
        normal_load = weight * inv_norm
        grade_force = -weight * grade * inv_norm
        rolling_force = c_rr * normal_load
        hold_force = grade_force if grade_force >= 0.0 else -grade_force
        min_load = min_load_frac * weight

        throttle = accel_cmd if accel_cmd > 0.0 else 0.0
        brake = -accel_cmd if accel_cmd < 0.0 else 0.0
        brake_front = brake * max_brake_front
        brake_rear = brake * max_brake_rear

        s = self.state
        x = s.x
        y = s.y
        yaw = s.yaw
        vx = s.vx
        vy = s.vy
        r = s.yaw_rate
        steer = s.steer
        tyre_ax = s.tyre_ax
        alpha_f = 0.0
        alpha_r = 0.0
        ax = 0.0
        ay = 0.0
        blend = 1.0
        steer_mid = steer
        cos_d = cos(steer)
        sin_d = sin(steer)
        half_h = 0.5 * h
        inv_h = 1.0 / h
        cos_y = cos(yaw)
        sin_y = sin(yaw)
        world_vx = vx * cos_y - vy * sin_y
        world_vy = vx * sin_y + vy * cos_y
        front_load_static = normal_load * front_share
        rear_load_static = normal_load * rear_share

        for _ in range(substeps):
            # Steering actuator: slew toward the target. The forces see the substep's mean
            # angle, so the input is not advanced by a substep (which would shift the response
            # by h/2 and make the trajectory depend on the substep count).
            if steer != steer_target:
                d_steer = steer_target - steer
                if d_steer > max_steer_change:
                    d_steer = max_steer_change
                elif d_steer < -max_steer_change:
                    d_steer = -max_steer_change
                steer_mid = steer + 0.5 * d_steer
                steer += d_steer
                cos_d = cos(steer_mid)
                sin_d = sin(steer_mid)
            elif steer_mid != steer:
                steer_mid = steer
                cos_d = cos(steer)
                sin_d = sin(steer)

            # Normal loads with longitudinal load transfer from the previous substep.
            transfer = transfer_gain * tyre_ax
            fz_f = front_load_static - transfer
            fz_r = rear_load_static + transfer
            if fz_f < min_load:
                fz_f = min_load
            if fz_r < min_load:
                fz_r = min_load

            # Slip angles as the direction of each axle's velocity in its wheel frame. Taking
            # |longitudinal velocity| keeps the lateral force opposing lateral sliding when the
            # car rolls backwards after a spin.
            vy_front_axle = vy + lf * r
            vx_wheel_f = vx * cos_d + vy_front_axle * sin_d
            vy_wheel_f = vy_front_axle * cos_d - vx * sin_d
            alpha_f = atan2(vy_wheel_f, vx_wheel_f if vx_wheel_f >= 0.0 else -vx_wheel_f)
            alpha_r = atan2(vy - lr * r, vx if vx >= 0.0 else -vx)

            # Longitudinal tyre forces, limited by each axle's friction.
            mu_f = mu0_f - mu_slope_f * fz_f
            if mu_f < mu_min_f:
                mu_f = mu_min_f
            mu_r = mu0_r - mu_slope_r * fz_r
            if mu_r < mu_min_r:
                mu_r = mu_min_r
            cap_f = mu_f * fz_f
            cap_r = mu_r * fz_r
            # Friction ellipse: the lateral capacity shrinks with the longitudinal force carried.
            if throttle > 0.0:
                speed_abs = vx if vx >= 0.0 else -vx
                fx_r = throttle * (power / speed_abs if speed_abs * max_drive > power else max_drive)
                if fx_r > cap_r:
                    fx_r = cap_r  # wheelspin
                long_r = fx_r / cap_r
                ell_r = 1.0 - long_r * long_r
                ell_r = sqrt(ell_r) if ell_r > 0.0 else 0.0
                ell_f = 1.0
                brake_f_abs = 0.0
                brake_r_abs = 0.0
            elif brake > 0.0:
                fx_r = 0.0
                brake_f_abs = brake_front if brake_front < cap_f else cap_f  # lock-up above cap
                brake_r_abs = brake_rear if brake_rear < cap_r else cap_r
                long_f = brake_f_abs / cap_f
                long_r = brake_r_abs / cap_r
                # Near standstill the tyres only carry the force that stops (or holds) the car
                # within the substep; the rest of their grip stays available sideways.
                stopping_force = (vx if vx >= 0.0 else -vx) * mass * inv_h + hold_force
                if brake_f_abs + brake_r_abs > stopping_force:
                    scale = stopping_force / (brake_f_abs + brake_r_abs)
                    long_f *= scale
                    long_r *= scale
                ell_f = 1.0 - long_f * long_f
                ell_r = 1.0 - long_r * long_r
                ell_f = sqrt(ell_f) if ell_f > 0.0 else 0.0
                ell_r = sqrt(ell_r) if ell_r > 0.0 else 0.0
            else:
                fx_r = 0.0
                brake_f_abs = 0.0
                brake_r_abs = 0.0
                ell_f = 1.0
                ell_r = 1.0

            # Pacejka lateral forces (wheel frame), opposing the lateral slip.
            ba = bf * alpha_f
            fy_f = -ell_f * cap_f * sin(cf * atan(ba - ef * (ba - atan(ba))))
            ba = br * alpha_r
            fy_r = -ell_r * cap_r * sin(cr * atan(ba - er * (ba - atan(ba))))

            # Body-frame forces. Brakes and rolling resistance act as Coulomb friction on vx,
            # handled below so they stop the car instead of reversing it.
            speed = sqrt(vx * vx + vy * vy)
            drag_per_speed = drag_k * speed
            drag_x = drag_per_speed * vx
            fx_other = fx_r - fy_f * sin_d + grade_force - drag_x
            fx_resist = brake_f_abs * cos_d + brake_r_abs + rolling_force
            if vx_wheel_f >= 0.0:
                fy_front_body = fy_f * cos_d - brake_f_abs * sin_d
            else:
                fy_front_body = fy_f * cos_d + brake_f_abs * sin_d
            fy_body = fy_front_body + fy_r - drag_per_speed * vy

            ax_other = fx_other * inv_mass + vy * r
            a_resist = fx_resist * inv_mass
            if vx > 0.0:
                vx_new = vx + h * (ax_other - a_resist)
                if vx_new < 0.0 and ax_other <= a_resist:
                    vx_new = 0.0
            elif vx < 0.0:
                vx_new = vx + h * (ax_other + a_resist)
                if vx_new > 0.0 and ax_other >= -a_resist:
                    vx_new = 0.0
            elif ax_other > a_resist:
                vx_new = h * (ax_other - a_resist)
            elif ax_other < -a_resist:
                vx_new = h * (ax_other + a_resist)
            else:
                vx_new = 0.0  # held by brakes / rolling resistance
            tyre_ax = (vx_new - vx) * inv_h - vy * r + (drag_x - grade_force) * inv_mass
            ax = tyre_ax - drag_x * inv_mass  # what an accelerometer reads: tyres and drag

            dvy = fy_body * inv_mass - vx * r
            yaw_acc = (lf * fy_front_body - lr * fy_r) * inv_iz
            # Low-speed blend toward the kinematic bicycle, where the tyre forces would be too
            # stiff for explicit substeps and slip angles lose meaning: below the band the lateral
            # and yaw states relax to their no-slip values (no faster than friction allows), and
            # inside the band the two models are mixed.
            blend = (speed - blend_low) * inv_blend_band
            if blend < 1.0:
                if blend < 0.0:
                    blend = 0.0
                tan_d = sin_d / cos_d
                # Grip left beside the longitudinal acceleration (friction circle).
                lat_room = 1.0 - (tyre_ax * tyre_ax) / (max_lat_acc * max_lat_acc)
                lat_room = sqrt(lat_room) if lat_room > 0.0 else 0.0
                max_kin_dvy = max_lat_acc * lat_room
                max_kin_yaw_acc = max_yaw_acc * lat_room
                kin_dvy = kin_rate * (vx * lr * tan_d * inv_wheelbase - vy)
                if kin_dvy > max_kin_dvy:
                    kin_dvy = max_kin_dvy
                elif kin_dvy < -max_kin_dvy:
                    kin_dvy = -max_kin_dvy
                kin_yaw_acc = kin_rate * (vx * tan_d * inv_wheelbase - r)
                if kin_yaw_acc > max_kin_yaw_acc:
                    kin_yaw_acc = max_kin_yaw_acc
                elif kin_yaw_acc < -max_kin_yaw_acc:
                    kin_yaw_acc = -max_kin_yaw_acc
                dvy = blend * dvy + (1.0 - blend) * kin_dvy
                yaw_acc = blend * yaw_acc + (1.0 - blend) * kin_yaw_acc
            vy_new = vy + h * dvy
            r_new = r + h * yaw_acc
            if speed < standstill:
                # Crawling: settle exactly on the kinematic values instead of decaying forever.
                tan_d = sin_d / cos_d
                vy_new = vx_new * lr * tan_d * inv_wheelbase
                r_new = vx_new * tan_d * inv_wheelbase

            ay = (vy_new - vy) * inv_h + vx * r
            # Pose by the trapezoidal rule on the velocities (second order at no extra cost).
            yaw += half_h * (r + r_new)
            vx = vx_new
            vy = vy_new
            r = r_new
            cos_y = cos(yaw)
            sin_y = sin(yaw)
            world_vx_new = vx * cos_y - vy * sin_y
            world_vy_new = vx * sin_y + vy * cos_y
            x += half_h * (world_vx + world_vx_new)
            y += half_h * (world_vy + world_vy_new)
            world_vx = world_vx_new
            world_vy = world_vy_new

        if yaw > math.pi or yaw < -math.pi:
            yaw = math.remainder(yaw, _TWO_PI)
        s.x = x
        s.y = y
        s.yaw = yaw
        s.vx = vx
        s.vy = vy
        s.yaw_rate = r
        s.steer = steer
        s.tyre_ax = tyre_ax
        s.ax = ax
        s.ay = ay
        # Slip angles fade out with the dynamic model below the blend band (the kinematic model
        # has none); the sideslip of a car at rest is defined as zero.
        dynamic_share = 1.0 if blend >= 1.0 else (blend if blend > 0.0 else 0.0)
        s.slip_angle_front = -alpha_f * dynamic_share
        s.slip_angle_rear = -alpha_r * dynamic_share
        s.speed = speed = math.sqrt(vx * vx + vy * vy)
        s.sideslip = math.atan2(vy, vx) if speed >= standstill else 0.0
        return s
