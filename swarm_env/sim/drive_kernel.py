"""The differential-drive velocity callback of :mod:`swarm_env.sim.world`, compiled to a C function.

Chipmunk calls a robot's velocity callback in every physics substep (:func:`swarm_env.sim.bodies.velocity_callback`
says why the wheel velocity is set there). Dispatched to Python through cffi, those calls were the
largest single cost of a step after the contact solver (~60 µs of a ~360 µs step of
``paper_cbs_switch``: ``python -m cProfile``); this module builds the same callback as a numba
``cfunc`` that chipmunk calls directly.

How it reaches the robot's state: the callback gets only the ``cpBody *``. The drive state (the
``body.drive`` array ``[v_cmd, omega_cmd, v, omega, dv_max, domega_max]``, NaN = no limit) is
found through the body's torque field, which holds the array's address: chipmunk reads a body's
force and torque only in its default velocity callback, which a driven robot never runs, and
nothing here applies forces. The angle and velocities are read and written at their offsets in
``struct cpBody`` (chipmunk 7's layout on 64-bit builds, checked once per process by probing a
body: :func:`probe_offsets`).

Same bits as the Python callback, by construction (the same operations on the same doubles:
``min``/``max`` as Python evaluates them, the C library's ``cos``/``sin``) and by a self-test that
steps one small world both ways before the first use (:func:`available`); anything unexpected (an
unknown pymunk layout, a platform whose calling convention passes ``cpVect`` differently, a
failed self-test) leaves the Python callback in place. Only where the C calling convention passes
a two-double struct in two float registers (x86-64 System V, AArch64): there the callback's
signature ``(cpBody *, cpVect, cpFloat, cpFloat)`` is the cfunc's ``(void *, double, double,
double, double)``.
"""

from __future__ import annotations

import math
import platform
import struct
import sys
from typing import Any

import numba
from numba import types
from numba.extending import intrinsic

from swarm_env.kernel_cache import cfunc
from swarm_env.sim.bodies import robot_body, velocity_callback

_STATE: dict[str, Any] = {}  # "ok": whether the compiled callback passed its checks here


def probe_offsets() -> dict[str, int] | None:
    """Byte offsets of a body's position, velocity, angle, angular velocity and torque in ``struct cpBody`` (found
    by setting distinctive values through pymunk and finding them in the struct's memory; the position's first
    copy: chipmunk keeps it again in the body's transform). ``None`` if a value is missing or ambiguous."""
    import pymunk
    from pymunk._chipmunk import ffi

    body = pymunk.Body(1.0, 2.0)
    marks = {"px": 7.389056098930, "py": -1.414213562373, "a": 1.2345678901234, "vx": -3.141592653589,
             "vy": 2.718281828459, "w": 0.57721566490153, "t": 1.6180339887499}
    body.position = (marks["px"], marks["py"])
    body.angle = marks["a"]
    body.velocity = (marks["vx"], marks["vy"])
    body.angular_velocity = marks["w"]
    body.torque = marks["t"]
    raw = bytes(ffi.buffer(ffi.cast("char *", body._body), 512))
    found: dict[str, int] = {}
    for name, value in marks.items():
        hits = [off for off in range(0, len(raw) - 7, 8) if struct.unpack_from("d", raw, off)[0] == value]
        if not hits or (len(hits) > 1 and name not in ("px", "py")):
            return None
        found[name] = hits[0]
    if found["vy"] != found["vx"] + 8:
        return None
    return found


#: Where chipmunk 7's ``struct cpBody`` keeps a body's position, velocity, angle, angular velocity and torque, in
#: bytes from the start (64-bit builds); :func:`probe_offsets` checks them in this process before any kernel that
#: reads or writes a body directly (this callback, :mod:`swarm_env.vector.world_batch`) is used.
BODY_OFFSETS = {"px": 64, "py": 72, "vx": 80, "vy": 88, "a": 112, "w": 120, "t": 128}
_I_VX, _I_VY, _I_A, _I_W, _I_T = (BODY_OFFSETS[k] // 8 for k in ("vx", "vy", "a", "w", "t"))
_SIZE = _I_T + 1


@intrinsic
def _as_pointer(typingctx: Any, address: Any) -> Any:  # pragma: no cover - compile time: int64 -> void *
    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        return builder.inttoptr(args[0], context.get_value_type(types.voidptr))

    return types.voidptr(types.int64), codegen


@cfunc(types.void(types.voidptr, types.float64, types.float64, types.float64, types.float64),
             error_model="numpy")
def _drive(body, gx, gy, damping, dt):  # pragma: no cover - compiled
    """:func:`swarm_env.sim.bodies.velocity_callback` on the raw ``cpBody``."""
    doubles = numba.carray(body, (_SIZE,), numba.float64)
    words = numba.carray(body, (_SIZE,), numba.int64)
    st = numba.carray(_as_pointer(words[_I_T]), (6,), numba.float64)
    v, w = st[2], st[3]
    dv, dw = st[4], st[5]
    if dv != dv:  # NaN: no acceleration limit
        v = st[0]
    else:  # v + min(max(v_cmd - v, -dv * dt), dv * dt), as Python's min/max pick
        step = st[0] - v
        lo = -dv * dt
        if lo > step:
            step = lo
        hi = dv * dt
        if hi < step:
            step = hi
        v = v + step
    if dw != dw:
        w = st[1]
    else:
        step = st[1] - w
        lo = -dw * dt
        if lo > step:
            step = lo
        hi = dw * dt
        if hi < step:
            step = hi
        w = w + step
    st[2] = v
    st[3] = w
    a = doubles[_I_A]
    doubles[_I_VX] = v * math.cos(a)
    doubles[_I_VY] = v * math.sin(a)
    doubles[_I_W] = w


def _supported_platform() -> bool:
    machine = platform.machine().lower()
    return sys.platform.startswith(("linux", "darwin")) and machine in ("x86_64", "amd64", "arm64", "aarch64")


def available() -> bool:
    """Whether the compiled callback can be installed in this process (decided once: probes the
    layout, compiles, and checks it against the Python callback on a small world)."""
    if "ok" not in _STATE:
        _STATE["ok"] = False
        try:
            if _supported_platform():
                if probe_offsets() == BODY_OFFSETS:
                    _STATE["ok"] = _self_test()
        except Exception:  # noqa: BLE001 - any surprise keeps the Python callback
            _STATE["ok"] = False
    return bool(_STATE["ok"])


def install(body: Any) -> bool:
    """Make ``body``'s velocity callback the compiled one (its ``drive`` array must be a C-contiguous
    float64 array of 6, kept on the body as long as the callback is installed). ``False`` (nothing
    changed) where the compiled callback is not :func:`available`."""
    if not available():
        return False
    state = body.drive
    if state.dtype.char != "d" or state.shape != (6,) or not state.flags.c_contiguous:
        raise ValueError("body.drive must be a C-contiguous float64 array of 6")
    _attach(body)
    return True


def _attach(body: Any) -> None:
    from pymunk._chipmunk import ffi, lib

    state = body.drive
    ffi.cast("int64_t *", body._body)[_I_T] = state.ctypes.data
    callback = ffi.cast("cpBodyVelocityFunc", _drive.address)
    body._fast_drive = (callback, state)  # keeps the state alive as long as the callback (and the body)
    lib.cpBodySetVelocityUpdateFunc(body._body, callback)


def _self_test() -> bool:
    """Step a small world with the Python callback and with the compiled one: the same bits?"""
    import copy

    import numpy as np
    import pymunk


    def make() -> tuple[pymunk.Space, list[pymunk.Body]]:
        space = pymunk.Space()
        space.add(pymunk.Segment(space.static_body, (-1.0, -0.35), (5.0, 0.4), 0.05))
        bodies = []
        for k, limits in enumerate(((None, None), (0.9, 2.5), (0.4, None))):
            body = robot_body((0.6 * k, 0.1 * k), 0.3 * k - 0.4, 0.2, limits)
            space.add(body, pymunk.Circle(body, 0.2))
            bodies.append(body)
        return space, bodies

    space_py, bodies_py = make()
    space_c, bodies_c = copy.deepcopy((space_py, bodies_py))
    for body in bodies_py:
        body.velocity_func = velocity_callback
    for body in bodies_c:
        _attach(body)
    rng = np.random.default_rng(0)
    for _ in range(40):
        cmd = rng.uniform(-1.0, 1.0, (len(bodies_py), 2)).tolist()
        for bodies in (bodies_py, bodies_c):
            for body, (v, w) in zip(bodies, cmd):
                body.drive[0], body.drive[1] = v, 2.0 * w
        for _sub in range(4):
            space_py.step(0.025)
            space_c.step(0.025)
    a = [(tuple(b.position), b.angle, tuple(b.velocity), b.angular_velocity, b.drive.tobytes()) for b in bodies_py]
    b = [(tuple(b.position), b.angle, tuple(b.velocity), b.angular_velocity, b.drive.tobytes()) for b in bodies_c]
    return a == b and any(p[2] != (0.0, 0.0) for p in a)


__all__ = ["available", "install"]
