"""Robot bodies and their drive law: the reference that the compiled drive callback must match bit for bit.

A robot is a pymunk disc whose wheels are a unicycle command ``(v, omega)``, applied in every physics substep by
its velocity callback (:func:`velocity_callback`, the reference; :func:`install_python_callback`, the same
operations through a cffi callback; :mod:`swarm_env.sim.drive_kernel`, compiled). :func:`robot_body` builds
one with the reference callback; :class:`~swarm_env.sim.world.World` then installs the fastest callback that
gives its bits. Also here: pymunk's body property accessors and its cffi handles, called directly by the world.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pymunk

#: kg; equal masses, so two robots pushing each other split the difference.
ROBOT_MASS = 10.0


# Body property accessors, called directly: pymunk's Body routes every attribute assignment
# through a Python-level __setattr__, which made up a third of the physics step's cost (the
# callback below runs for every robot in every substep).
_BODY: Any = pymunk.Body  # (typed loosely: pymunk's stubs declare these properties as overloads)
body_angle = _BODY.angle.fget
set_body_velocity = _BODY.velocity.fset
set_body_angular_velocity = _BODY.angular_velocity.fset
set_body_position = _BODY.position.fset


def advance_twist(drive: np.ndarray, dt: float) -> tuple[float, float]:
    """Move the realised twist of ``drive`` (see :func:`velocity_callback`) towards the command for ``dt`` s."""
    v_cmd, w_cmd, v, w, dv, dw = drive.tolist()
    v = v_cmd if dv != dv else v + min(max(v_cmd - v, -dv * dt), dv * dt)  # dv != dv: NaN, no limit
    w = w_cmd if dw != dw else w + min(max(w_cmd - w, -dw * dt), dw * dt)
    drive[2] = v
    drive[3] = w
    return v, w


def velocity_callback(body: pymunk.Body, gravity: Any, damping: float, dt: float) -> None:
    """pymunk velocity callback of a differential-drive robot.

    Chipmunk integrates positions *before* it solves contacts and integrates
    velocities *after* it, so a velocity set from outside between two steps
    goes straight into the position update and pushes the robot into walls
    (measured: 0.11 m of overlap at 0.65 m/s). Setting the wheel velocity here
    lets the contact solver correct it within the same substep.

    ``body.drive`` is the float64 array ``[v_cmd, omega_cmd, v, omega, dv_max, domega_max]``:
    the commanded twist, the realised one (updated in place: moved towards the
    command by at most ``dv_max``/``domega_max`` per second, NaN = no limit).
    :mod:`swarm_env.sim.drive_kernel` compiles the same callback (installed where it passes its
    self-test); :func:`install_python_callback` is the next fastest, then this function.
    """
    v, w = advance_twist(body.drive, dt)
    a = body_angle(body)
    set_body_velocity(body, (v * math.cos(a), v * math.sin(a)))
    set_body_angular_velocity(body, w)


try:  # pymunk's cffi handles: optional, only for the faster callback below
    from pymunk._chipmunk import ffi as CP_FFI
    from pymunk._chipmunk import lib as CP_LIB
except ImportError:  # pragma: no cover - other pymunk builds
    CP_FFI = CP_LIB = None


def install_python_callback(body: pymunk.Body) -> None:
    """Replace ``body``'s velocity callback, at the C level, by one doing exactly what
    :func:`velocity_callback` does (same float operations on the same ``body.drive`` list).

    pymunk dispatches a Python velocity callback through a generic trampoline (a handle
    lookup and a Vec2d per call); a cffi callback bound to this body skips both, which
    saves about a third of the physics step. The callback object lives on the body
    (``_fast_drive``: not pickled, pymunk skips ``_`` attributes); pymunk still reports
    and pickles :func:`velocity_callback`, so a copied space falls back to it (same numbers) until
    :class:`World` installs a new one. Does nothing where pymunk's internals differ.
    """
    if CP_FFI is None:
        return
    try:
        handle = body._body
        get_angle = CP_LIB.cpBodyGetAngle
        set_velocity = CP_LIB.cpBodySetVelocity
        set_angular_velocity = CP_LIB.cpBodySetAngularVelocity
        set_func = CP_LIB.cpBodySetVelocityUpdateFunc
        state = body.drive
        cos, sin, advance = math.cos, math.sin, advance_twist

        def drive(cbody: Any, gravity: Any, damping: float, dt: float) -> None:
            v, w = advance(state, dt)
            a = get_angle(cbody)
            set_velocity(cbody, (v * cos(a), v * sin(a)))
            set_angular_velocity(cbody, w)

        callback = CP_FFI.callback("cpBodyVelocityFunc", drive)
    except Exception:  # noqa: BLE001 - unknown pymunk internals or no executable memory: keep velocity_callback
        return
    body._fast_drive = callback  # keeps the C function alive as long as the body
    set_func(handle, callback)


def robot_body(position: tuple[float, float], angle: float, radius: float,
               limits: tuple[float | None, float | None]) -> pymunk.Body:
    """A differential-drive robot's body of ``radius`` at ``position``/``angle``, with acceleration ``limits``
    ``(dv_max, domega_max)`` (None: no limit) and the reference velocity callback."""
    body = pymunk.Body(ROBOT_MASS, pymunk.moment_for_circle(ROBOT_MASS, 0.0, radius))
    body.position = position
    body.angle = angle
    body.drive = np.array([0.0, 0.0, 0.0, 0.0, *(math.nan if x is None else float(x) for x in limits)])
    body.velocity_func = velocity_callback
    return body


__all__ = ["CP_FFI", "CP_LIB", "ROBOT_MASS", "advance_twist", "body_angle", "install_python_callback", "robot_body",
           "set_body_angular_velocity", "set_body_position", "set_body_velocity", "velocity_callback"]
