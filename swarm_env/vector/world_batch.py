"""The physics and the snapshot of M worlds in one compiled call.

For each of ``M`` :class:`~swarm_env.sim.world.World` s, :meth:`WorldBatch.step_and_snapshot` does what

    for m in range(M):
        worlds[m].step(commands[m])
        states[m] = worlds[m].snapshot()

does, **bit for bit** (every :class:`~swarm_env.state.WorldState` field, the contacts, and the
worlds' own state afterwards, so a world can go on stepping by itself or in a batch). The per-world
loop spends most of its time around the C work: tens of Python calls, small arrays and a
``WorldState`` per world. Here one numba function (:func:`_batch_step`) loops over the worlds and,
for each, computes the scripted humans' substep states, clips the commands into the drive states,
moves the humans and steps the chipmunk space substep after substep
(:func:`swarm_env.sim.physics_kernel._substeps`, the same C calls), reads the followers' bodies straight
from chipmunk's ``cpBody`` structs, and places the virtual leader and the formation slots
(:mod:`swarm_env.geometry.slot_kernel`'s inner functions); all results land in a handful of ``(M, ...)``
blocks allocated once per call, and each world's ``WorldState`` holds read-only views of its rows.
The blocks are new every call, so a ``WorldState`` stays valid after later steps (the experts and
``final_world_state`` keep them). :meth:`WorldBatch.last_arrays` hands the blocks, stacked, to a
caller that wants the per-step arrays of all worlds (the engine's batched stages: no gathering from
``M`` snapshots), and ``on_states`` lets it take each chunk's snapshots as soon as they exist.

Which worlds take the batched path: those :meth:`World.step <swarm_env.sim.world.World.step>` itself
would step with :func:`swarm_env.sim.physics_kernel.scripted_step` and a compiled virtual leader, i.e.
the compiled kernels are on and work here (:func:`available`), the space is quiet
(:meth:`World._space_quiet <swarm_env.sim.world.World._space_quiet>`: not a world's first step, nothing
deferred, no foreign collision handler...), the leader is ``virtual``, every human is ``scripted``,
formations have at most 32 slots and the command has the world's ``(n, 2)`` shape. Every other
world (a robot leader, reactive humans, a world's first step, kernels off) is stepped by its own
``step()`` and ``snapshot()``, in the same call; the results are the same either way.

How the kernel reaches each world's data: by address. A world's record (built when the batch first
sees it, see :class:`WorldBatch`) holds the addresses of its space, its follower and human bodies,
its drive states, its humans' packed paths, its leader's packed path, its slot screen and its
formation offsets; the arrays behind them are kept alive by the record and the world. A world
replaced in the batch (auto-reset builds a new ``World``) gets a new record; the others are not
touched. Collision callbacks (pymunk's, in Python) still run from inside ``cpSpaceStep``: the kernel
holds the GIL, as :mod:`swarm_env.sim.physics_kernel`'s does.

Body fields are read at their offsets in chipmunk 7's ``struct cpBody`` (64-bit builds), which
:func:`available` checks once per process by probing a body (as :mod:`swarm_env.sim.drive_kernel`
does); anything unexpected sends every world down its own ``step()``.

Use from an engine: keep one :class:`WorldBatch` and hand it the current worlds every step (an
auto-reset's new ``World`` is then taken in by identity)::

    batch = WorldBatch()
    states = batch.step_and_snapshot(commands, worlds=[env._world for env in envs])  # (M, N, 2) commands

This module imports numba (the kernel compiles at first use, ~8 s, then loads from numba's cache):
import it lazily where the compiled kernels are off (:func:`swarm_env.compiled.compiled_kernels`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, Literal

import numba
import numpy as np

from swarm_env.compiled import compiled_kernels
from swarm_env.geometry.slot_kernel import _place_slots, _screen, _virtual_pose
from swarm_env.kernel_cache import njit
from swarm_env.sim.drive_kernel import BODY_OFFSETS, _as_pointer, probe_offsets
from swarm_env.sim.human_kernel import fill_states
from swarm_env.sim.physics_kernel import _substeps
from swarm_env.sim.snapshot_kernel import fill_follower
from swarm_env.sim.world import _FAST_SPACE_STEP, World, _finish_step
from swarm_env.state import WorldState

__all__ = ["WorldBatch", "available", "step_and_snapshot"]

# A body's doubles that _batch_step reads, at chipmunk's offsets (checked in this process by available()).
_I_PX, _I_PY, _I_VX, _I_VY, _I_A, _I_W = (BODY_OFFSETS[k] // 8 for k in ("px", "py", "vx", "vy", "a", "w"))
_BODY_DOUBLES = _I_W + 1

# Columns of the per-world integer table (addresses and sizes) and float table.
(_C_SPACE, _C_N, _C_H, _C_SUBSTEPS, _C_STEP, _C_DRIVES, _C_FOLLOWERS, _C_HUMANS, _C_HTABLE, _C_HVERTS, _C_NVERTS,
 _C_HSEGS, _C_NSEGS, _C_PATH, _C_NPATH, _C_SCREEN, _C_NSCREEN, _C_SIZE_REACH, _C_NFORM, _C_AT, _C_OFFSETS) = range(21)
_INT_COLS = 21
_F_SUB_DT, _F_DT, _F_VMAX, _F_WMAX, _F_T0, _F_LENGTH, _F_SPEED, _F_DELAY = range(8)
_FLOAT_COLS = 8

_STATE: dict[str, Any] = {}


def available() -> bool:
    """Whether the batched path can run in this process (decided once): the compiled physics kernel
    passed its self-test (:func:`swarm_env.sim.physics_kernel.available`) and chipmunk's body layout is
    the one :func:`_batch_step` reads. Where not, :meth:`WorldBatch.step_and_snapshot` steps every
    world by its own ``step()``/``snapshot()``."""
    if "ok" not in _STATE:
        _STATE["ok"] = False
        try:
            from swarm_env.sim import physics_kernel

            if physics_kernel.available() and probe_offsets() == BODY_OFFSETS:
                _STATE["fns"] = physics_kernel.functions()
                _STATE["ok"] = True
        except Exception:  # noqa: BLE001 - any surprise keeps the per-world path
            _STATE["ok"] = False
    return bool(_STATE["ok"])


@njit(error_model="numpy")  # not nogil: chipmunk calls back into Python
def _batch_step(fns, rows, ints, flts, commands, n_max, h_max):  # pragma: no cover - compiled
    """Step worlds ``rows`` (indices into the tables ``ints`` ``(M, _INT_COLS)`` and ``flts``
    ``(M, _FLOAT_COLS)``, see :class:`_Record`) with ``commands[m]`` ``(n_max, 2)``, as
    :meth:`World.step <swarm_env.sim.world.World.step>` does on its scripted-humans compiled path, and read
    what :meth:`~swarm_env.sim.world.World.snapshot` reads. ``fns``: :func:`swarm_env.sim.physics_kernel.functions`.
    Returns blocks whose row ``r`` belongs to world ``rows[r]``: the followers' pose, velocity, twist
    and the unprojected slots ``(R, n_max, .)``, whether the slots passed the screen, the leader's
    pose, velocity, twist and done flag, the humans' positions and velocities ``(R, h_max, 2)`` (rows
    beyond a world's own humans are 0), the new time, formation index and next switch time."""
    m_count = rows.shape[0]
    pose = np.empty((m_count, n_max, 3))
    vel = np.empty((m_count, n_max, 2))
    twist = np.empty((m_count, n_max, 2))
    slots = np.empty((m_count, n_max, 2))
    free = np.zeros(m_count, dtype=np.bool_)
    lpose = np.empty((m_count, 3))
    lvel = np.empty((m_count, 2))
    ltwist = np.empty((m_count, 2))
    done = np.zeros(m_count, dtype=np.bool_)
    hpos_out = np.zeros((m_count, h_max, 2))
    hvel_out = np.zeros((m_count, h_max, 2))
    times = np.zeros(m_count)
    form = np.zeros(m_count, dtype=np.int64)
    next_switch = np.zeros(m_count)
    leader = np.empty(6)
    for r in range(rows.shape[0]):
        m = rows[r]
        n = ints[m, _C_N]
        h = ints[m, _C_H]
        count = ints[m, _C_SUBSTEPS]
        step_count = ints[m, _C_STEP]
        sub_dt = flts[m, _F_SUB_DT]
        dt = flts[m, _F_DT]
        t0 = flts[m, _F_T0]
        # the scripted humans at each substep and at the end of the step (physics_kernel._scripted_step)
        table = numba.carray(_as_pointer(ints[m, _C_HTABLE]), (h, 7), numba.float64)
        verts = numba.carray(_as_pointer(ints[m, _C_HVERTS]), (ints[m, _C_NVERTS], 3), numba.float64)
        segs = numba.carray(_as_pointer(ints[m, _C_HSEGS]), (ints[m, _C_NSEGS], 3), numba.float64)
        hpos = np.zeros((count + 1, h, 2))
        hvel = np.zeros((count + 1, h, 2))
        for k in range(count):
            fill_states(t0 + k * sub_dt, table, verts, segs, hpos[k], hvel[k])
        fill_states((step_count + 1) * dt, table, verts, segs, hpos[count], hvel[count])
        humans = numba.carray(_as_pointer(ints[m, _C_HUMANS]), (h,), numba.int64)
        drives = numba.carray(_as_pointer(ints[m, _C_DRIVES]), (n, 6), numba.float64)
        _substeps(fns, ints[m, _C_SPACE], sub_dt, count, humans, hpos, hvel, commands[m], flts[m, _F_VMAX],
                  flts[m, _F_WMAX], drives)
        for j in range(h):
            hpos_out[r, j, 0] = hpos[count, j, 0]
            hpos_out[r, j, 1] = hpos[count, j, 1]
            hvel_out[r, j, 0] = hvel[count, j, 0]
            hvel_out[r, j, 1] = hvel[count, j, 1]
        # the followers' bodies (World.snapshot: _BodyReader.read, then snapshot_kernel.follower_arrays)
        bodies = numba.carray(_as_pointer(ints[m, _C_FOLLOWERS]), (n,), numba.int64)
        for i in range(n):
            b = numba.carray(_as_pointer(bodies[i]), (_BODY_DOUBLES,), numba.float64)
            fill_follower(b[_I_PX], b[_I_PY], b[_I_A], b[_I_VX], b[_I_VY], b[_I_W], pose[r, i], vel[r, i], twist[r, i])
        # the clock, the formation schedule, the virtual leader and the slots (World.step's end)
        t = (step_count + 1) * dt
        times[r] = t
        n_form = ints[m, _C_NFORM]
        at = numba.carray(_as_pointer(ints[m, _C_AT]), (n_form,), numba.float64)
        idx = 0
        nxt = np.inf
        for i in range(n_form):
            if at[i] <= t:
                idx = i
            if at[i] > t and at[i] < nxt:
                nxt = at[i]
        form[r] = idx
        next_switch[r] = nxt
        path = numba.carray(_as_pointer(ints[m, _C_PATH]), (ints[m, _C_NPATH], 6), numba.float64)
        _virtual_pose(path, flts[m, _F_LENGTH], flts[m, _F_SPEED], t, flts[m, _F_DELAY], leader)
        offsets = numba.carray(_as_pointer(ints[m, _C_OFFSETS]), (n_form, n, 2), numba.float64)
        _place_slots(leader[0], leader[1], leader[2], offsets[idx], slots[r, :n])
        screen = numba.carray(_as_pointer(ints[m, _C_SCREEN]), (ints[m, _C_NSCREEN], 3), numba.float64)
        size_reach = numba.carray(_as_pointer(ints[m, _C_SIZE_REACH]), (3,), numba.float64)
        free[r] = _screen(slots[r, :n], screen, size_reach)
        lpose[r, 0] = leader[0]
        lpose[r, 1] = leader[1]
        lpose[r, 2] = leader[2]
        lvel[r, 0] = leader[3]
        lvel[r, 1] = leader[4]
        ltwist[r, 0] = math.hypot(leader[3], leader[4])  # World.snapshot: np.hypot, libm's hypot too
        ltwist[r, 1] = 0.0
        done[r] = leader[5] != 0.0
    return (pose, vel, twist, slots, free, lpose, lvel, ltwist, done, hpos_out, hvel_out, times, form,
            next_switch)


class _Record:
    """What the kernel needs of one world that does not change while the world lives: its rows of the
    integer and float tables, and the arrays behind the addresses in them (kept alive here)."""

    __slots__ = ("ints", "flts", "keep", "n", "h")

    def __init__(self, world: World) -> None:
        from swarm_env.geometry import slot_kernel
        from swarm_env.sim import physics_kernel
        from swarm_env.sim.human_kernel import PackedHumans

        scn = world.scenario
        self.n, self.h = world.n, len(world._human_bodies)
        if world._packed_humans is None:  # the caches World.step builds at first use
            world._packed_humans = PackedHumans(scn.humans, world._human_paths)
        if world._leader_packed is None:
            world._leader_packed = slot_kernel.pack_path(world._leader_path)
        screen, size_reach = world._screen()
        humans = world._packed_humans
        space_ptr, human_handles = physics_kernel.addresses(world.space, world._human_bodies)
        _, follower_handles = physics_kernel.addresses(world.space, world._bodies)
        at = np.array([float(f.at) for f in scn.formations], dtype=np.float64)
        offsets = np.ascontiguousarray(np.stack(world._offsets), dtype=np.float64)
        keep = (world._drives, human_handles, follower_handles, humans.table, humans.vertices, humans.segments,
                world._leader_packed, screen, size_reach, at, offsets)
        for arr in keep:
            if not (arr.flags.c_contiguous and arr.dtype in (np.float64, np.int64)):
                raise ValueError("world_batch: an array the kernel reads by address is not C-contiguous float64/int64")

        def addr(a: np.ndarray) -> int:
            return int(a.ctypes.data)

        self.ints = np.array([space_ptr, self.n, self.h, world.substeps, 0, addr(world._drives),
                              addr(follower_handles), addr(human_handles), addr(humans.table), addr(humans.vertices),
                              len(humans.vertices), addr(humans.segments), len(humans.segments),
                              addr(world._leader_packed), len(world._leader_packed), addr(screen), len(screen),
                              addr(size_reach), len(at), addr(at), addr(offsets)], dtype=np.int64)
        robots, leader = scn.robots, scn.leader
        self.flts = np.array([world.sub_dt, world.dt, float(robots.max_speed), float(robots.max_turn_rate), 0.0,
                              world._leader_path.length, leader.speed, leader.start_delay], dtype=np.float64)
        self.keep = keep


def _batchable(world: World) -> bool:
    """Whether ``world`` can ever take the batched path (what does not change while it lives): the
    cases where :meth:`World.step <swarm_env.sim.world.World.step>` runs ``physics_kernel.scripted_step``
    and the compiled virtual leader, and the snapshot reads only the followers' bodies."""
    scn = world.scenario
    return (type(world) is World and world._leader_body is None and not len(world._reactive)
            and all(len(o) == world.n for o in world._offsets) and world.n <= 32  # World._SLOT_KERNEL_MAX
            and all(float(f.at) == f.at for f in scn.formations)
            and world._drives is not None and world._drives.shape == (world.n, 6)
            and all(b.drive.base is world._drives for b in world._bodies))


class WorldBatch:
    """``M`` worlds whose physics and snapshots are computed together (see the module docstring).

    Args:
        worlds: the worlds, in order; world ``m`` gets ``commands[m]``.
        chunk: how many worlds one compiled call steps (the same results for any value).

    The batch keeps a record per world (addresses and packed arrays, ~20 µs to build). Replace a
    world with :meth:`replace`, or pass the current list to :meth:`step_and_snapshot` (``worlds=``):
    every world that is not the one the batch holds at its index is taken in and recorded anew.
    """

    def __init__(self, worlds: Sequence[World] = (), chunk: int = 64) -> None:
        if chunk < 1:
            raise ValueError(f"chunk must be >= 1, got {chunk}")
        #: Worlds per compiled call (see :meth:`_step_batched`).
        self.chunk = int(chunk)
        self._worlds: list[World] = []
        self._records: list[_Record | Literal[False] | None] = []  # None: not built yet; False: never batchable
        self._ints = np.zeros((0, _INT_COLS), dtype=np.int64)
        self._flts = np.zeros((0, _FLOAT_COLS), dtype=np.float64)
        for w in worlds:
            self._append(w)
        #: How many worlds the last :meth:`step_and_snapshot` stepped on the batched path.
        self.last_batched = 0
        # The last step's compiled calls: (rows, the kernel's blocks, projected slots, worlds touching,
        # worlds with contact onsets) per chunk (last_arrays).
        self._last: list[tuple[np.ndarray, tuple, list[tuple[int, np.ndarray]], list[int], list[int]]] = []

    def __len__(self) -> int:
        return len(self._worlds)

    @property
    def worlds(self) -> list[World]:
        """The worlds, in order (a copy of the list)."""
        return list(self._worlds)

    def _append(self, world: World) -> None:
        m = len(self._worlds)
        self._worlds.append(world)
        self._records.append(None)
        if m >= len(self._ints):
            grow = max(8, 2 * len(self._ints))
            self._ints = np.concatenate([self._ints, np.zeros((grow, _INT_COLS), dtype=np.int64)])
            self._flts = np.concatenate([self._flts, np.zeros((grow, _FLOAT_COLS), dtype=np.float64)])

    def replace(self, m: int, world: World) -> None:
        """Put ``world`` in place of world ``m`` (e.g. the new ``World`` of an auto-reset)."""
        if not 0 <= m < len(self._worlds):
            raise IndexError(f"world index {m} out of range for a batch of {len(self._worlds)}")
        self._worlds[m] = world
        self._records[m] = None

    def _sync(self, worlds: Sequence[World]) -> None:
        if len(worlds) < len(self._worlds):
            del self._worlds[len(worlds):]
            del self._records[len(worlds):]
        held = self._worlds
        for m, w in enumerate(worlds):
            if m >= len(held):
                self._append(w)
            elif w is not held[m]:
                self.replace(m, w)

    def _record(self, m: int) -> _Record | None:
        """World ``m``'s record, built at first need; ``None`` for a world that cannot be batched."""
        rec = self._records[m]
        if rec is None:
            w = self._worlds[m]
            if not _batchable(w):
                self._records[m] = False
                return None
            rec = self._records[m] = _Record(w)
            self._ints[m] = rec.ints
            self._flts[m] = rec.flts
        return rec if isinstance(rec, _Record) else None

    def step_and_snapshot(self, commands: np.ndarray, worlds: Sequence[World] | None = None,
                          on_states: Callable[[list[int], list[Any]], None] | None = None) -> list[WorldState]:
        """Step every world with its command and return the worlds' snapshots: what
        ``[(w.step(c), w.snapshot())[1] for w, c in zip(worlds, commands)]`` returns, bit for bit,
        with the worlds left in the same state.

        Args:
            commands: ``(M, N, 2)`` float ``(v, omega)`` per follower and world (world ``m`` with
                ``n != N`` followers takes its own ``step()``, which then rejects or accepts the
                command as it does).
            worlds: the current worlds; where given, the batch first takes in every world that is
                not the one it holds at that index (and drops the ones beyond ``len(worlds)``).
            on_states: called as ``on_states(indices, states)`` as soon as the snapshots of the
                worlds ``indices`` are in ``states`` (the list returned at the end), chunk after
                chunk, then once for the worlds stepped by themselves; every world once, each
                call's indices ascending. The engine stores each world's new snapshot there while
                the chunk's objects are still in the caches (and the previous snapshots are freed
                chunk by chunk rather than all at the end).

        After the call, :meth:`last_arrays` gives the snapshots' per-step arrays stacked (when every
        world took the batched path)."""
        if worlds is not None:
            self._sync(worlds)
        held = self._worlds
        cmd = np.ascontiguousarray(commands, dtype=np.float64)
        if cmd.ndim != 3 or cmd.shape[0] != len(held) or cmd.shape[2] != 2:
            raise ValueError(f"commands must be (M={len(held)}, N, 2), got shape {np.shape(commands)}")
        states: list[Any] = [None] * len(held)
        self._last = []
        if _FAST_SPACE_STEP and compiled_kernels() and available():
            self._step_batched(cmd, states, on_states)
        else:
            self.last_batched = 0
        rest = [m for m, s in enumerate(states) if s is None]
        for m in rest:  # the rest: the worlds' own step and snapshot
            w = held[m]
            w.step(cmd[m])
            states[m] = w.snapshot()
        if on_states is not None and rest:
            on_states(rest, states)
        return states

    def last_arrays(self) -> dict[str, Any] | None:
        """The per-step arrays of the last :meth:`step_and_snapshot`'s snapshots, stacked on a world
        axis, when every world took the batched path (else ``None``): what stacking the snapshots'
        fields gives, bit for bit, read from the kernel's blocks instead of ``M`` snapshots.

        Keys: ``pose`` ``(M, N, 3)``, ``vel``, ``twist`` and ``slots`` (the slot targets, moved out of
        obstacles where a world did) ``(M, N, 2)``, ``lpose`` ``(M, 3)``, ``lvel`` and ``ltwist``
        ``(M, 2)``, ``hpos`` and ``hvel`` ``(M, H, 2)`` (world ``m``'s humans in its first ``hcount[m]``
        rows, zeros after; ``H``: the most humans of a world), ``hcount``, ``time``, ``step``,
        ``leader_done``, ``k`` (formation index), ``next_switch`` ``(M,)``, and ``touching`` /
        ``contacts``: the worlds (ascending) whose snapshot has pairs in touch / contact onsets.
        New, writeable arrays (the snapshots keep their own read-only ones)."""
        chunks = self._last
        m = len(self._worlds)
        if self.last_batched != m or not chunks:
            return None
        outs = [c[1] for c in chunks]
        width = max(o[9].shape[1] for o in outs)

        def stacked(k: int) -> np.ndarray:
            return np.concatenate([o[k] for o in outs]) if len(outs) > 1 else outs[0][k].copy()

        def humans(k: int) -> np.ndarray:
            if all(o[k].shape[1] == width for o in outs):
                return stacked(k)
            out = np.zeros((m, width, 2))
            at = 0
            for o in outs:
                out[at:at + len(o[k]), :o[k].shape[1]] = o[k]
                at += len(o[k])
            return out

        rows = np.concatenate([c[0] for c in chunks])
        arrays: dict[str, Any] = {
            "pose": stacked(0), "vel": stacked(1), "twist": stacked(2), "slots": stacked(3), "lpose": stacked(5),
            "lvel": stacked(6), "ltwist": stacked(7), "leader_done": stacked(8), "hpos": humans(9),
            "hvel": humans(10), "time": stacked(11), "k": stacked(12), "next_switch": stacked(13),
            "hcount": self._ints[rows, _C_H], "step": self._ints[rows, _C_STEP] + 1,
            "touching": [m for c in chunks for m in c[3]], "contacts": [m for c in chunks for m in c[4]],
        }
        for c in chunks:
            for m_, s in c[2]:  # slots moved out of an obstacle (World._advance_virtual_leader_and_slots)
                arrays["slots"][m_] = s
        return arrays

    def _step_batched(self, cmd: np.ndarray, states: list[Any],
                      on_states: Callable[[list[int], list[Any]], None] | None) -> None:
        """Step the worlds that can take the batched path and put their snapshots in ``states``,
        :attr:`chunk` worlds at a time, so a world's Python objects are touched before and after its
        physics with at most ``chunk - 1`` other worlds' work in between (at 1,024 worlds the Python
        part costs ~3x more per world than at 64: the worlds' objects no longer stay in the caches
        from one step to the next; chunks of 16 to 1,024 measured alike on a loaded machine)."""
        self.last_batched = 0
        for start in range(0, len(self._worlds), self.chunk):
            self.last_batched += self._step_chunk(range(start, min(start + self.chunk, len(self._worlds))), cmd,
                                                  states, on_states)

    def _step_chunk(self, chunk: range, cmd: np.ndarray, states: list[Any],
                    on_states: Callable[[list[int], list[Any]], None] | None) -> int:
        held, records = self._worlds, self._records
        n_cmd = cmd.shape[1]
        rows: list[int] = []
        clocks: list[int] = []
        t0s: list[float] = []
        h_max = 0
        try:
            for m in chunk:
                w = held[m]
                rec = records[m]
                if rec is None:
                    rec = self._record(m)
                if not rec or rec.n != n_cmd or not w._space_quiet():
                    continue
                rows.append(m)
                clocks.append(w.step_count)
                t0s.append(w.time)
                if rec.h > h_max:
                    h_max = rec.h
                w._touched_step = set(w._touching)  # as World.step before its physics
                w.space._locked = True  # as pymunk's Space.step during chipmunk's step
            if not rows:
                return 0
            idx = np.array(rows, dtype=np.int64)
            ints, flts = self._ints, self._flts
            ints[idx, _C_STEP] = clocks
            flts[idx, _F_T0] = t0s
            out = _batch_step(_STATE["fns"], idx, ints, flts, cmd, n_cmd, h_max)
        finally:
            for m in rows:  # as World.step after chipmunk's step
                space = held[m].space
                space._removed_shapes.clear()
                space._locked = False
                if space._add_later or space._remove_later or space._post_step_callbacks:
                    _finish_step(space)
        pose, vel, twist, slots, free, lpose, lvel, ltwist, done, hpos, hvel, times, form, next_switch = out
        for arr in (pose, vel, twist, slots, lpose, lvel, ltwist, hpos, hvel):
            arr.flags.writeable = False  # the snapshots' arrays are views of these blocks
        pose_l, vel_l, twist_l, slots_l = list(pose), list(vel), list(twist), list(slots)
        lpose_l, lvel_l, ltwist_l, hpos_l, hvel_l = list(lpose), list(lvel), list(ltwist), list(hpos), list(hvel)
        free_l, done_l, times_l, form_l = free.tolist(), done.tolist(), times.tolist(), form.tolist()
        next_l = next_switch.tolist()
        build_state = WorldState.build
        projected: list[tuple[int, np.ndarray]] = []
        touching: list[int] = []
        contacts: list[int] = []
        for r, m in enumerate(rows):
            w = held[m]
            h = records[m].h  # type: ignore[union-attr]
            hp, hv, s, lp, lv = hpos_l[r], hvel_l[r], slots_l[r], lpose_l[r], lvel_l[r]
            if h != h_max:
                hp, hv = hp[:h], hv[:h]
            # World.step's end, with the kernel's numbers
            step_count = w.step_count = w.step_count + 1
            t = w.time = times_l[r]
            if h:
                w._human_pos, w._human_vel = hp, hv
            f = w.formation_index = form_l[r]
            w._virtual_pose, w._virtual_vel = lp, lv
            ldone = w._leader_done = done_l[r]
            if not free_l[r]:  # a slot too close to an obstacle: as World._advance_virtual_leader_and_slots
                s = w.static.project_free(s, w._slot_clearance)
                s.flags.writeable = False
                projected.append((m, s))
            w._slots = s
            w._settle_contacts()
            touched, onsets = w._touching_step, w._onsets
            if touched:
                touching.append(m)
                if onsets:
                    contacts.append(m)
            # World.snapshot's WorldState (the same fields, the same order)
            states[m] = build_state(
                time=t,
                step=step_count,
                follower_pose=pose_l[r],
                follower_vel=vel_l[r],
                follower_twist=twist_l[r],
                follower_radius=w._follower_radius,
                leader_pose=lp,
                leader_vel=lv,
                leader_twist=ltwist_l[r],
                leader_radius=0.0,
                leader_done=ldone,
                human_pos=hp,
                human_vel=hv,
                human_radius=w._human_radius,
                slot_targets=s,
                formation_index=f,
                next_switch_time=next_l[r],
                contacts=onsets,
                static=w.static,
                scenario=w.scenario,
                touching=touched,
            )
        self._last.append((idx, out, projected, touching, contacts))
        if on_states is not None:
            on_states(rows, states)
        return len(rows)


def step_and_snapshot(worlds_or_batch: WorldBatch | Sequence[World], commands: np.ndarray) -> list[WorldState]:
    """``[(w.step(c), w.snapshot())[1] for w, c in zip(worlds, commands)]``, bit for bit, batched
    (:meth:`WorldBatch.step_and_snapshot`). Pass a :class:`WorldBatch` kept from step to step: given
    a plain list of worlds, this builds a new batch (and a record per world) on every call."""
    batch = worlds_or_batch if isinstance(worlds_or_batch, WorldBatch) else WorldBatch(worlds_or_batch)
    return batch.step_and_snapshot(commands)

