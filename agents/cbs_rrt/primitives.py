"""Motion primitives of paper 000 (Sec. III-B): drive a fixed distance forward while turning.

A primitive ``k`` moves the robot ``step`` metres along a circular arc that turns
its heading by ``angles[k]`` radians (a straight segment for a zero angle), at
the constant speed ``speed``. Exact arc geometry, in the robot's frame (x
forward, y left), with curvature ``kappa = angle / step`` and arc length
``s in [0, step]``::

    x(s) = sin(kappa s) / kappa,   y(s) = (1 - cos(kappa s)) / kappa,   theta(s) = kappa s

(``x = s, y = 0`` when ``kappa = 0``). The twist that drives it is
``(v, omega) = (speed, angle * speed / step)``, held for ``step / speed`` seconds.

Each primitive is also described by ``samples`` points spaced evenly along the
arc (arc length ``step * j / samples``, ``j = 1..samples``): collision checks
look at those points and timed paths store them, so the straight chord between
two consecutive samples stays within ``step^2 |kappa| / (8 samples^2)`` of the
arc (4 mm for the defaults).

Optional *spins* (``spin_deg``) turn the robot in place by the given angles at
``spin_rate``: a differential-drive robot can, and without them a robot that
faces an obstacle closer than its turning radius (``step / max angle``) has no
valid forward primitive at all. Paper 000 lists forward primitives only, so the
default set has no spins; the expert adds +-45 and +-90 degrees.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from swarm_env_agents.cbs_rrt.kernels import Prims, plain

__all__ = ["PAPER_ANGLES_DEG", "MotionPrimitives"]

#: Paper 000's turn angles (degrees): straight, then +-12, +-24, +-36, +-48 (left first).
PAPER_ANGLES_DEG: tuple[float, ...] = (0.0, 12.0, -12.0, 24.0, -24.0, 36.0, -36.0, 48.0, -48.0)


def _arc(kappa: float, s: np.ndarray) -> np.ndarray:
    """Local poses ``(len(s), 3)`` at arc lengths ``s`` along an arc of curvature ``kappa``."""
    if abs(kappa) < 1e-12:
        return np.column_stack([s, np.zeros_like(s), np.zeros_like(s)])
    th = kappa * s
    return np.column_stack([np.sin(th) / kappa, (1.0 - np.cos(th)) / kappa, th])


@dataclass(frozen=True, eq=False)
class MotionPrimitives:
    """A set of forward arc primitives, optionally with spins (see the module docstring).

    Args:
        angles_deg: heading change of each forward primitive (degrees, counter-clockwise
            positive). Default: paper 000's ``0, +-12, +-24, +-36, +-48``.
        step: arc length of every forward primitive (m, > 0).
        speed: driving speed along a forward primitive (m/s, > 0); it lasts ``step / speed`` s.
        samples: points per primitive stored along it (>= 1).
        spin_deg: turn-in-place angles (degrees, non-zero); default none.
        spin_rate: turn rate of a spin (rad/s, > 0 if there are spins).

    Derived read-only arrays (``P`` primitives, forward ones first, then spins;
    ``S = samples``):
        angles: ``(P,)`` heading changes (rad); ``kappa``: ``(P,)`` curvature of the
        forward ones (1/m, 0 for spins); ``twist``: ``(P, 2)`` the ``(v, omega)`` that
        drives each; ``end``: ``(P, 3)`` local end pose; ``local``: ``(P, S, 3)`` local
        poses of the samples (the last one is ``end``); ``durations``: ``(P,)`` seconds;
        ``sample_t``: ``(P, S)`` time of each sample after the primitive's start;
        ``is_spin``: ``(P,)``; ``kernel``: the library as the compiled kernels take it (a
        :class:`.kernels.Prims`, as the plain tuple of :func:`.kernels.plain`).
    """

    angles_deg: tuple[float, ...] = PAPER_ANGLES_DEG
    step: float = 0.42
    speed: float = 0.35
    samples: int = 6
    spin_deg: tuple[float, ...] = ()
    spin_rate: float = 0.7
    angles: np.ndarray = field(init=False, repr=False)
    kappa: np.ndarray = field(init=False, repr=False)
    twist: np.ndarray = field(init=False, repr=False)
    end: np.ndarray = field(init=False, repr=False)
    local: np.ndarray = field(init=False, repr=False)
    durations: np.ndarray = field(init=False, repr=False)
    sample_t: np.ndarray = field(init=False, repr=False)
    is_spin: np.ndarray = field(init=False, repr=False)
    # Flattened (P*S,) local sample coordinates, for one rotation of all samples at once.
    _lx: np.ndarray = field(init=False, repr=False)
    _ly: np.ndarray = field(init=False, repr=False)
    kernel: tuple = field(init=False, repr=False)

    def __post_init__(self) -> None:
        put = object.__setattr__
        ang = tuple(float(a) for a in self.angles_deg)
        spins = tuple(float(a) for a in self.spin_deg)
        if not ang:
            raise ValueError("at least one forward primitive angle is needed")
        if not all(math.isfinite(a) and abs(a) < 180.0 for a in ang):
            raise ValueError(f"primitive angles must be finite and within (-180, 180) degrees, got {ang}")
        if not all(math.isfinite(a) and 0.0 < abs(a) <= 180.0 for a in spins):
            raise ValueError(f"spin angles must be finite, non-zero and within [-180, 180] degrees, got {spins}")
        if not (math.isfinite(self.step) and self.step > 0):
            raise ValueError(f"step must be > 0, got {self.step!r}")
        if not (math.isfinite(self.speed) and self.speed > 0):
            raise ValueError(f"speed must be > 0, got {self.speed!r}")
        if spins and not (math.isfinite(self.spin_rate) and self.spin_rate > 0):
            raise ValueError(f"spin_rate must be > 0, got {self.spin_rate!r}")
        if int(self.samples) < 1:
            raise ValueError(f"samples must be >= 1, got {self.samples!r}")
        put(self, "angles_deg", ang)
        put(self, "spin_deg", spins)
        put(self, "samples", int(self.samples))
        S = self.samples
        frac = np.arange(1, S + 1) / S
        fwd = np.radians(np.array(ang, dtype=np.float64))
        spin = np.radians(np.array(spins, dtype=np.float64))
        kappa = np.concatenate([fwd / self.step, np.zeros(len(spin))])
        local = [_arc(float(k), self.step * frac) for k in fwd / self.step]  # construction only
        local += [np.column_stack([np.zeros(S), np.zeros(S), a * frac]) for a in spin]
        local_arr = np.stack(local)  # (P, S, 3)
        fwd_time = self.step / self.speed
        durations = np.concatenate([np.full(len(fwd), fwd_time), np.abs(spin) / self.spin_rate if len(spin) else []])
        twist = np.column_stack(
            [np.concatenate([np.full(len(fwd), self.speed), np.zeros(len(spin))]), np.concatenate([fwd, spin]) / durations]
        )
        for name, arr in (
            ("angles", np.concatenate([fwd, spin])),
            ("kappa", kappa),
            ("twist", twist),
            ("end", local_arr[:, -1, :].copy()),
            ("local", local_arr),
            ("durations", durations),
            ("sample_t", durations[:, None] * frac[None, :]),
            ("is_spin", np.concatenate([np.zeros(len(fwd), bool), np.ones(len(spin), bool)])),
            ("_lx", local_arr[:, :, 0].ravel().copy()),
            ("_ly", local_arr[:, :, 1].ravel().copy()),
        ):
            arr.flags.writeable = False
            put(self, name, arr)
        put(self, "kernel", plain(Prims(self._lx, self._ly, self.sample_t.ravel(), self.local, self.sample_t,
                                        self.angles, self.durations, len(self.angles), self.samples)))

    @property
    def duration(self) -> float:
        """Duration of a forward primitive (s)."""
        return float(self.step / self.speed)

    @property
    def omega(self) -> np.ndarray:
        """``(P,)`` turn rate of each primitive (rad/s)."""
        return self.twist[:, 1]

    @classmethod
    def for_robot(
        cls,
        max_speed: float,
        max_turn_rate: float,
        *,
        angles_deg: Sequence[float] = PAPER_ANGLES_DEG,
        speed_fraction: float = 0.7,
        step: float | None = None,
        samples: int = 6,
        spin_deg: Sequence[float] = (),
    ) -> MotionPrimitives:
        """Primitives sized for a robot: ``speed = speed_fraction * max_speed`` and
        ``spin_rate = speed_fraction * max_turn_rate`` (the rest is the tracking
        controller's slack) and, by default, ``step = max_speed * max|angle| /
        max_turn_rate`` — the distance of the env's discrete primitive (``SwarmEnv``'s
        ``T_p = 48 deg / max_turn_rate`` at ``max_speed``).

        Raises ``ValueError`` when the sharpest primitive would need a turn rate above
        ``max_turn_rate`` at that speed.
        """
        amax = math.radians(max(abs(float(a)) for a in angles_deg))
        if step is None:
            step = max_speed * amax / max_turn_rate if amax > 0 else max_speed
        prims = cls(
            tuple(angles_deg), float(step), float(speed_fraction * max_speed), samples,
            tuple(spin_deg), float(speed_fraction * max_turn_rate),
        )
        if float(np.abs(prims.omega).max()) > max_turn_rate * (1.0 + 1e-9):
            raise ValueError(
                f"the sharpest primitive turns at {float(np.abs(prims.omega).max()):.3f} rad/s > max_turn_rate "
                f"{max_turn_rate}: use a longer step or a lower speed"
            )
        return prims

    @property
    def count(self) -> int:
        return len(self.angles)

    def expand(self, pose: Sequence[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All primitives from one world pose ``(x, y, theta)``.

        Returns ``xs, ys`` ``(P*S,)`` world coordinates of every sample (primitive-major:
        samples of primitive ``k`` are ``[k*S, (k+1)*S)``) and ``ends`` ``(P, 3)`` world end
        poses (theta not wrapped).
        """
        x, y, th = float(pose[0]), float(pose[1]), float(pose[2])
        c, s = math.cos(th), math.sin(th)
        xs = x + c * self._lx - s * self._ly
        ys = y + s * self._lx + c * self._ly
        last = self.samples - 1
        ends = np.empty((len(self.angles), 3))
        ends[:, 0] = xs[last:: self.samples]
        ends[:, 1] = ys[last:: self.samples]
        ends[:, 2] = th + self.angles
        return xs, ys, ends

    def poses(self, pose: Sequence[float], k: int) -> np.ndarray:
        """``(S, 3)`` world poses of the samples of primitive ``k`` from ``pose`` (theta not wrapped)."""
        x, y, th = float(pose[0]), float(pose[1]), float(pose[2])
        c, s = math.cos(th), math.sin(th)
        loc = self.local[k]
        out = np.empty((len(loc), 3))  # (column_stack's own overhead was most of this hot call's cost)
        lx, ly = loc[:, 0], loc[:, 1]
        out[:, 0] = x + c * lx - s * ly
        out[:, 1] = y + s * lx + c * ly
        out[:, 2] = th + loc[:, 2]
        return out

    def classify(self, a: Sequence[float], b: Sequence[float], tol: float = 1e-6) -> int:
        """Index of the primitive that takes pose ``a`` exactly to pose ``b`` (within ``tol``
        in metres and radians), or ``-1`` if none does."""
        ends = self.expand(a)[2]
        dpos = np.hypot(ends[:, 0] - b[0], ends[:, 1] - b[1])
        dth = np.abs((ends[:, 2] - b[2] + math.pi) % (2 * math.pi) - math.pi)
        ok = np.flatnonzero((dpos <= tol) & (dth <= tol))
        return int(ok[0]) if len(ok) else -1
