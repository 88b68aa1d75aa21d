"""A control step's physics substeps in one compiled call: the kinematic humans moved and chipmunk
stepped, substep after substep, from numba calling chipmunk's C functions.

:meth:`swarm_env.sim.world.World.step` moves each human (``cpBodySetPosition`` and
``cpBodySetVelocity``) and steps the space (``cpSpaceStep``) in every substep. The C work is a few
microseconds; calling it from Python (a cffi call per body and per step, and the loop) cost several
times that. :func:`substeps` makes exactly the same C calls in the same order with the same
doubles, from one numba function that gets the functions' and objects' addresses.

Collision callbacks still run: ``cpSpaceStep`` calls pymunk's Python callbacks, which take the GIL
the compiled function holds (it is compiled without ``nogil``). The world uses this path only when
pymunk's ``Space.step`` would do nothing else between two substeps (see
:meth:`~swarm_env.sim.world.World.step`).

Where it applies: chipmunk's ``cpVect`` (two doubles) passed by value goes in two floating-point
registers (x86-64 System V, AArch64), so ``cpBodySetPosition(cpBody *, cpVect)`` is called as
``(void *, double, double)``, as :mod:`swarm_env.sim.drive_kernel` assumes for its callback; a
self-test (:func:`available`) steps a small space both ways before the first use and anything
unexpected leaves the Python path in place.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from swarm_env.kernel_cache import njit
from swarm_env.sim.human_kernel import fill_states

_STATE: dict[str, Any] = {}

_I8P = ir.IntType(8).as_pointer()


@intrinsic
def _call_step(typingctx: Any, fn: Any, space: Any, dt: Any) -> Any:  # pragma: no cover - compile time
    """``((void (*)(cpSpace *, double)) fn)(space, dt)``."""

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        fnty = ir.FunctionType(ir.VoidType(), [_I8P, ir.DoubleType()])
        fptr = builder.inttoptr(args[0], fnty.as_pointer())
        builder.call(fptr, [builder.inttoptr(args[1], _I8P), args[2]])
        return context.get_dummy_value()

    return types.void(types.int64, types.int64, types.float64), codegen


@intrinsic
def _call_set_vect(typingctx: Any, fn: Any, body: Any, x: Any, y: Any) -> Any:  # pragma: no cover - compile time
    """``((void (*)(cpBody *, cpVect)) fn)(body, (cpVect){x, y})``, the vector in two registers."""

    def codegen(context: Any, builder: Any, signature: Any, args: Any) -> Any:
        fnty = ir.FunctionType(ir.VoidType(), [_I8P, ir.DoubleType(), ir.DoubleType()])
        fptr = builder.inttoptr(args[0], fnty.as_pointer())
        builder.call(fptr, [builder.inttoptr(args[1], _I8P), args[2], args[3]])
        return context.get_dummy_value()

    return types.void(types.int64, types.int64, types.float64, types.float64), codegen


@njit(nogil=True, error_model="numpy")
def _clip(x, limit):  # pragma: no cover - compiled
    """``min(max(x, -limit), limit)`` with Python's ``min``/``max`` semantics (see :func:`clip_commands`)."""
    lo = -limit
    if lo > x:
        x = lo
    if limit < x:
        x = limit
    return x


@njit(nogil=True, error_model="numpy")
def clip_commands(command, v_max, w_max, drives):  # pragma: no cover - compiled
    """``drives[i, 0:2] = min(max(v, -v_max), v_max), min(max(w, -w_max), w_max)`` for each row
    ``(v, w)`` of ``command``: Python's ``min``/``max`` (the later argument wins only when strictly
    smaller / larger), as :meth:`swarm_env.sim.world.World.step` clips on Python floats."""
    for i in range(command.shape[0]):
        drives[i, 0] = _clip(command[i, 0], v_max)
        drives[i, 1] = _clip(command[i, 1], w_max)


@njit(error_model="numpy")  # not nogil: chipmunk calls back into Python
def _scripted_step(ptrs, consts, t0, step_count, count, table, vertices, segments, command, drives
                   ):  # pragma: no cover - compiled
    n = table.shape[0]
    sub_dt, dt = consts[0], consts[1]
    pos = np.zeros((count + 1, n, 2))
    vel = np.zeros((count + 1, n, 2))
    for k in range(count):  # the times World._human_substates asks for, the same float operations
        fill_states(t0 + k * sub_dt, table, vertices, segments, pos[k], vel[k])
    fill_states((step_count + 1) * dt, table, vertices, segments, pos[count], vel[count])
    _substeps(ptrs[0:3], ptrs[3], sub_dt, count, ptrs[4:], pos, vel, command, consts[2], consts[3], drives)
    return pos, vel


@njit(error_model="numpy")  # not nogil: chipmunk calls back into Python
def _substeps(fns, space, dt, count, bodies, pos, vel, command, v_max, w_max, drives):  # pragma: no cover - compiled
    clip_commands(command, v_max, w_max, drives)
    step_fn, set_pos, set_vel = fns[0], fns[1], fns[2]
    for k in range(count):
        for j in range(bodies.shape[0]):
            _call_set_vect(set_pos, bodies[j], pos[k, j, 0], pos[k, j, 1])
            _call_set_vect(set_vel, bodies[j], vel[k, j, 0], vel[k, j, 1])
        _call_step(step_fn, space, dt)
    if pos.shape[0] > count:  # the end of the step's positions: snap the bodies there
        for j in range(bodies.shape[0]):
            _call_set_vect(set_pos, bodies[j], pos[count, j, 0], pos[count, j, 1])


def _address(ptr: Any) -> int:
    from pymunk._chipmunk import ffi

    return int(ffi.cast("uintptr_t", ptr))


def _functions() -> np.ndarray:
    from pymunk._chipmunk import ffi, lib

    return np.array([_address(ffi.addressof(lib, name)) for name in ("cpSpaceStep", "cpBodySetPosition",
                                                                      "cpBodySetVelocity")], dtype=np.int64)


def addresses(space: Any, bodies: list[Any]) -> tuple[int, np.ndarray]:
    """The C addresses :func:`substeps` takes: ``space``'s and each body's (valid while they live)."""
    return _address(space._space), np.array([_address(b._body) for b in bodies], dtype=np.int64)


def substeps(space: int, dt: float, bodies: np.ndarray, pos: np.ndarray, vel: np.ndarray, count: int,
             command: np.ndarray, v_max: float, w_max: float, drives: np.ndarray) -> None:
    """A control step's physics: first :func:`clip_commands` ``(command, v_max, w_max, drives)``
    (the robots' drive states, float64 ``(>= len(command), 6)``), then for ``k`` in ``range(count)``:
    set body ``j`` (addresses from :func:`addresses`) to position ``pos[k, j]`` and velocity
    ``vel[k, j]`` (``cpBodySetPosition``, ``cpBodySetVelocity``, body by body), then
    ``cpSpaceStep(space, dt)``; where ``pos`` has a row ``count``, last set each body's position to
    it (``cpBodySetPosition``). ``command``, ``pos``, ``vel``: C-contiguous float64. The caller locks
    the pymunk space (as ``Space.step`` does) and checks that nothing else is due between
    substeps. Only where :func:`available`."""
    _substeps(_STATE["fns"], space, float(dt), int(count), bodies, pos, vel, command, float(v_max), float(w_max),
              drives)


def scripted_step(ptrs: np.ndarray, consts: np.ndarray, t0: float, step_count: int, count: int, humans: Any,
                  command: np.ndarray, drives: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`substeps` for a world whose humans are all scripted, with their positions and
    velocities computed in the same call: at ``t0 + k * sub_dt`` for substep ``k`` and at
    ``(step_count + 1) * dt`` (the end of the step), as :meth:`PackedHumans.states_at` gives them.

    ``ptrs`` int64: ``cpSpaceStep``, ``cpBodySetPosition``, ``cpBodySetVelocity`` (:func:`functions`),
    the space, then the humans' bodies (:func:`addresses`); ``consts``: ``(sub_dt, dt, v_max, w_max)``;
    ``humans``: their :class:`~swarm_env.sim.human_kernel.PackedHumans`. Returns ``(positions,
    velocities)``, each ``(count + 1, H, 2)``."""
    return _scripted_step(ptrs, consts, float(t0), int(step_count), int(count), humans.table, humans.vertices,
                          humans.segments, command, drives)


def functions() -> np.ndarray:
    """The addresses of ``cpSpaceStep``, ``cpBodySetPosition``, ``cpBodySetVelocity`` (int64)."""
    return _STATE["fns"].copy()


def available() -> bool:
    """Whether :func:`substeps` can be used in this process (decided once: platform, compile, and a
    self-test against pymunk's own calls)."""
    if "ok" not in _STATE:
        _STATE["ok"] = False
        try:
            from swarm_env.sim.drive_kernel import _supported_platform

            if _supported_platform():
                _STATE["fns"] = _functions()
                _STATE["ok"] = _self_test()
        except Exception:  # noqa: BLE001 - any surprise keeps the Python path
            _STATE["ok"] = False
    return bool(_STATE["ok"])


def _self_test() -> bool:
    """Step a small space with a kinematic body and contacts through pymunk and through
    :func:`_substeps`: the same bits, and the collision callback seen the same number of times?"""

    import pymunk

    def make() -> tuple[pymunk.Space, list[pymunk.Body], list[int]]:
        space = pymunk.Space()
        space.gravity = (0.0, 0.0)
        space.add(pymunk.Segment(space.static_body, (-1.0, -0.35), (5.0, 0.4), 0.05))
        bodies = []
        for k in range(3):
            body = pymunk.Body(body_type=pymunk.Body.KINEMATIC) if k == 0 else pymunk.Body(1.0, 0.3)
            body.position = (0.5 * k, 0.05 * k)
            shape = pymunk.Circle(body, 0.3)
            shape.collision_type = 1 + (k > 0)
            space.add(body, shape)
            bodies.append(body)
        hits: list[int] = []
        space.on_collision(1, 2, begin=lambda arb, sp, data: hits.append(1))
        space.step(0.01)  # pymunk checks the new bodies in its first step
        return space, bodies, hits

    space_py, bodies_py, hits_py = make()
    space_c, bodies_c, hits_c = make()
    rng = np.random.default_rng(0)
    pos = rng.uniform(-0.5, 1.5, (12, 1, 2))
    vel = rng.uniform(-1.0, 1.0, (12, 1, 2))
    for k in range(12):
        bodies_py[0].position = tuple(pos[k, 0])
        bodies_py[0].velocity = tuple(vel[k, 0])
        space_py.step(0.025)
    space_ptr, handles = addresses(space_c, bodies_c[:1])
    _substeps(_STATE["fns"], space_ptr, 0.025, 12, handles, pos, vel, np.zeros((0, 2)), 1.0, 1.0, np.zeros((0, 6)))
    a = [(tuple(b.position), b.angle, tuple(b.velocity), b.angular_velocity) for b in bodies_py]
    b = [(tuple(b.position), b.angle, tuple(b.velocity), b.angular_velocity) for b in bodies_c]
    return a == b and len(hits_py) == len(hits_c) > 0 and any(p[0] != (0.0, 0.0) for p in a[1:])


__all__ = ["addresses", "available", "clip_commands", "functions", "scripted_step", "substeps"]
