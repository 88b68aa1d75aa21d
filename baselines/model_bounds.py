"""Bounds of saved policy files: what every policy loader checks before it reads, allocates or acts.

A run directory is input from anyone (a model downloaded with a paper is as untrusted as a scenario file), so
every loader of a saved policy reads its files through this module and checks the description with its
helpers before it builds a network: ``ppo:``/``sac:``/``bc:``/``sb3_ppo`` (:mod:`swarm_env_baselines.safe_io`,
:mod:`swarm_env_baselines.model_io`), the MAPPO family, ``residual_vo`` and ``isac:``
(:mod:`swarm_env_baselines.mappo_policy`), ``fan_dagger`` (:mod:`swarm_env_baselines.fan_policy`) and ``rllib:``
(:mod:`swarm_env_baselines.rllib_train`).

Files (:func:`read_bounded`, :func:`parse_json`, :func:`read_safetensors`):

* only a regular file is opened (``os.stat`` first; then opened without blocking and checked again), so a
  FIFO, a device or a directory is refused instead of read;
* a JSON description (``policy.json``) is at most :data:`MAX_DESCRIPTION_BYTES`, other JSON run files read
  the same way (a checkpoint's ``state.json``) at most :data:`MAX_STATE_BYTES`; JSON nests at most
  :data:`MAX_JSON_DEPTH` deep and is strict (no ``NaN``/``Infinity``);
* a weights file (``policy.safetensors``) is at most :data:`MAX_WEIGHTS_BYTES`; its header length (the first 8
  bytes) is read before the header, which is at most :data:`MAX_HEADER_BYTES` and lists at most
  :data:`MAX_TENSORS` tensors, each ``F32`` or ``F64`` of at most :data:`MAX_PARAMETERS` values; every value
  read is finite and at most :data:`MAX_ABS_WEIGHT` in magnitude (so a network of finite inputs cannot
  overflow to ``inf - inf``);
* a training checkpoint's ``state.safetensors`` (read on ``--resume``, :func:`read_checkpoint_tensors`) has wider
  bounds, since it also holds the optimizer's state, the pending rollout and generator states: at most
  :data:`MAX_CHECKPOINT_BYTES`, :data:`MAX_CHECKPOINT_TENSORS` tensors of the :data:`CHECKPOINT_DTYPES`, each at
  most :data:`MAX_CHECKPOINT_VALUES` values, whose bytes fill the file exactly; its floating-point values finite.

Descriptions (:func:`number`, :func:`integer`, :func:`widths`, :func:`vector`, :func:`statistics`,
:func:`check_parameters`, :func:`spec`): every number is an ``int``/``float`` (never a bool, a string, a list
or an object), finite and in range; hidden layers are 1-:data:`MAX_DEPTH` widths of 1-:data:`MAX_WIDTH`
units and a network at most :data:`MAX_PARAMETERS` parameters, counted before it is built; a network reads
at most :data:`MAX_INPUTS` values (the largest observation a scenario within :mod:`swarm_env.limits` gives,
plus an expert's action) and acts in :data:`ACTION_SIZE` values (a twist); normalisation statistics are
finite, ``var >= 0``, ``epsilon`` and ``clip`` finite and ``> 0``. Whether the sizes fit the env at hand (a
scenario with other sensors) is the policy's ``reset``: a misfit (:class:`~swarm_env.harness.policies.PolicyError`),
not a bad file.

Every check raises ``ValueError`` with one line, ``KEY: expected WHAT, got VALUE`` (values shown by
:func:`swarm_env.limits.clip_repr`, paths by :func:`swarm_env.limits.printable`); the loaders prefix the file
and the policy spec and raise it as a :class:`~swarm_env.harness.policies.ModelFileError`, which ``swarm-env``
prints as one line with exit code 2.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Collection, Iterator, Sequence
from typing import Any

import numpy as np

from swarm_env import reading
from swarm_env.limits import MAX_ABS_NUMBER, MAX_LIDAR_RAYS, MAX_NEIGHBORS, MAX_SENSED_HUMANS, clip_repr, printable
from swarm_env.reading import FileRefused, read_regular
from swarm_env.sensing.layout import ENTITY, FIXED

__all__ = [
    "ACTION_SIZE", "CHECKPOINT_DTYPES", "MAX_ABS_WEIGHT", "MAX_CHECKPOINT_BYTES", "MAX_CHECKPOINT_TENSORS",
    "MAX_CHECKPOINT_VALUES", "MAX_CLIP", "MAX_DEPTH", "MAX_DESCRIPTION_BYTES", "MAX_HEADER_BYTES", "MAX_INPUTS",
    "MAX_JSON_DEPTH", "MAX_OBSERVATION", "MAX_PARAMETERS", "MAX_SPEC_CHARS", "MAX_STATE_BYTES", "MAX_TENSORS",
    "MAX_WEIGHTS_BYTES", "MAX_WIDTH", "TENSOR_DTYPES", "check_parameters", "get", "integer", "json_object",
    "mlp_parameters", "number", "parse_json", "read_bounded", "read_checkpoint_tensors", "read_json",
    "read_safetensors", "shown", "spec", "statistics", "vector", "widths",
]

#: A training checkpoint's ``state.safetensors`` (read on ``--resume``): at most this many bytes, tensors and values
#: per tensor, of these dtypes (bytes per value). A default MAPPO checkpoint is ~10 MB; the rollout it keeps grows
#: with the worlds and steps per update.
MAX_CHECKPOINT_BYTES = 8 << 30
MAX_CHECKPOINT_TENSORS = 4096
MAX_CHECKPOINT_VALUES = 1 << 31
CHECKPOINT_DTYPES = {"F64": 8, "F32": 4, "F16": 2, "BF16": 2, "I64": 8, "I32": 4, "I16": 2, "I8": 1, "U8": 1,
                     "BOOL": 1}
#: The largest ``policy.json`` (bytes), checked before reading: the shipped ones are 3-18 kB.
MAX_DESCRIPTION_BYTES = 1 << 20
#: The largest other JSON run file read through :func:`read_json` (a checkpoint's ``state.json``, which keeps
#: the validation history), bytes.
MAX_STATE_BYTES = 64 << 20
#: Deepest nesting of JSON arrays and objects (the shipped descriptions nest 3 deep).
MAX_JSON_DEPTH = 32
#: Widest hidden layer (units) and most hidden layers of a network.
MAX_WIDTH, MAX_DEPTH = 4096, 16
#: Most parameters of one network (counted from its description before it is built): 64 MiB as float32.
MAX_PARAMETERS = 1 << 24
#: The longest observation a scenario within :mod:`swarm_env.limits` gives a follower
#: (``11 + 5 * neighbours + 5 * humans + lidar rays``, :mod:`swarm_env.sensing.layout`).
MAX_OBSERVATION = FIXED + ENTITY * (MAX_NEIGHBORS + MAX_SENSED_HUMANS) + MAX_LIDAR_RAYS
#: Values of one action: a twist (speed, turn rate), each in [-1, 1].
ACTION_SIZE = 2
#: The most inputs of a policy network: an observation and (a residual actor) its expert's action.
MAX_INPUTS = MAX_OBSERVATION + ACTION_SIZE
#: The largest normalisation ``clip`` (a normalised input is clipped to +-clip).
MAX_CLIP = MAX_ABS_NUMBER
#: The safetensors dtypes a policy file may hold, with their sizes (bytes).
TENSOR_DTYPES = {"F32": 4, "F64": 8}
#: Most tensors in one weights file (the shipped ones hold 12-13; a 16-layer SAC run with its critics ~200).
MAX_TENSORS = 1024
#: The longest safetensors header (the JSON after the 8-byte length), bytes.
MAX_HEADER_BYTES = 1 << 20
#: The largest weights file (bytes): four networks of :data:`MAX_PARAMETERS` float32 values (an actor, its
#: critics and their target copies) with the header.
MAX_WEIGHTS_BYTES = 4 * 4 * MAX_PARAMETERS + 8 + MAX_HEADER_BYTES
#: The largest magnitude of a saved weight (the shipped ones are below 10).
MAX_ABS_WEIGHT = MAX_ABS_NUMBER
#: The longest policy spec a description may name (a residual run's expert).
MAX_SPEC_CHARS = 1000


def shown(path: str | os.PathLike[str]) -> str:
    """``path`` for an error message: invisible characters escaped, long ones cut (one line, whatever its name)."""
    return printable(os.fspath(path), 400)


# --------------------------------------------------------------------------- files


def read_bounded(path: str | os.PathLike[str], max_bytes: int, what: str = "file") -> bytes:
    """The bytes of the regular file ``path`` (a symlink is followed), at most ``max_bytes``: the package's one
    bounded reader, :func:`swarm_env.reading.read_regular` (a FIFO, device, socket or directory refused without
    waiting; the size checked before reading; a file that grows meanwhile refused, never read on). Raises
    ``FileNotFoundError`` for a missing file and ``ValueError`` naming it for anything else.
    """
    with _refusals(path, max_bytes, what):
        return read_regular(path, max_bytes)


@contextlib.contextmanager
def _refusals(path: str | os.PathLike[str], max_bytes: int, what: str) -> Iterator[None]:
    """Word a :class:`~swarm_env.reading.FileRefused` raised in the block as this module's one-line ``ValueError``."""
    name = shown(path)
    try:
        yield
    except FileNotFoundError:
        raise
    except FileRefused as exc:
        if exc.kind is not None:
            raise ValueError(f"{name}: a {exc.kind}, not a regular file; refused") from None
        if exc.size is not None:
            raise ValueError(f"{name}: {exc.size:,} bytes, more than the {max_bytes:,} a {what} may have; refused "
                             "before reading") from None
        if exc.got is not None:  # it grew while it was read
            raise ValueError(f"{name}: more than the {max_bytes:,} bytes a {what} may have (it grew while being "
                             "read); refused") from None
        raise ValueError(f"{name}: cannot be read ({printable(exc.expected, 200)})") from None


def parse_json(data: bytes, max_depth: int = MAX_JSON_DEPTH) -> Any:
    """The JSON value of ``data``, nested at most ``max_depth`` deep and strict (the package's one JSON rule:
    :func:`swarm_env.reading.parse_json`). Raises ``ValueError`` (one line)."""
    return reading.parse_json(data, max_depth)


def read_json(path: str | os.PathLike[str], max_bytes: int = MAX_DESCRIPTION_BYTES, what: str = "policy description"
              ) -> Any:
    """The JSON value of the regular file ``path`` (:func:`read_bounded`, :func:`parse_json`). Raises
    ``FileNotFoundError`` for a missing file and ``ValueError`` naming the file for a bad one."""
    data = read_bounded(path, max_bytes, what)
    try:
        return parse_json(data)
    except ValueError as exc:
        raise ValueError(f"{shown(path)}: not a readable JSON {what} ({exc})") from None


def _safetensors_header(data: bytes, name: str, dtypes: Collection[str] = tuple(TENSOR_DTYPES),
                        max_tensors: int = MAX_TENSORS, max_values: int = MAX_PARAMETERS,
                        kind: str = "a policy file") -> dict[str, Any]:
    """The checked header of the safetensors bytes ``data`` (tensor name -> its entry): ``data`` holds at least
    the 8-byte length and the header it announces. At most ``max_tensors`` tensors, each of one of ``dtypes`` and
    at most ``max_values`` values."""
    bad = f"{name}: not a readable safetensors file, truncated or corrupt"
    if len(data) < 8:
        raise ValueError(f"{bad} ({len(data)} bytes, fewer than the 8 of the header length)")
    length = int.from_bytes(data[:8], "little")
    if length > MAX_HEADER_BYTES:
        raise ValueError(f"{name}: a safetensors header of {length:,} bytes, more than {MAX_HEADER_BYTES:,}; refused "
                         "before reading it")
    if 8 + length > len(data):
        raise ValueError(f"{bad} (a header of {length:,} bytes in a file of {len(data):,})")
    try:
        header = parse_json(data[8:8 + length])
    except ValueError as exc:
        raise ValueError(f"{bad} (header: {exc})") from None
    if not isinstance(header, dict):
        raise ValueError(f"{bad} (header: expected a JSON object, got {clip_repr(header)})")
    entries = {k: v for k, v in header.items() if k != "__metadata__"}
    if len(entries) > max_tensors:
        raise ValueError(f"{name}: {len(entries):,} tensors, more than the {max_tensors:,} {kind} may hold")
    for key, entry in entries.items():
        where = f"{name}: tensor {clip_repr(key)}"
        if not isinstance(entry, dict):
            raise ValueError(f"{bad} (tensor {clip_repr(key)}: expected an object, got {clip_repr(entry)})")
        dtype = entry.get("dtype")
        if dtype not in dtypes:
            raise ValueError(f"{where}: dtype {clip_repr(dtype)}, expected one of {', '.join(dtypes)}")
        shape = entry.get("shape")
        if (not isinstance(shape, list) or len(shape) > 4 or not all(type(n) is int and 0 <= n <= max_values
                                                                     for n in shape)):
            raise ValueError(f"{where}: shape {clip_repr(shape)}, expected a list of at most 4 sizes in "
                             f"0-{max_values:,}")
        if math.prod(shape) > max_values:
            raise ValueError(f"{where}: {math.prod(shape):,} values, more than {max_values:,}")
    return entries


def _finite(name: str, tensors: dict[str, Any], max_abs: float) -> None:
    """Refuse any floating-point tensor of ``tensors`` with a NaN, an infinity or a value beyond ``max_abs``."""
    import torch

    for key, tensor in tensors.items():
        if not tensor.numel() or not tensor.is_floating_point():
            continue
        if not bool(torch.isfinite(tensor).all()):
            raise ValueError(f"{name}: tensor {clip_repr(key)}: not all finite (NaN or infinity); expected finite "
                             "values")
        if float(tensor.abs().max()) > max_abs:
            raise ValueError(f"{name}: tensor {clip_repr(key)}: a value of magnitude {float(tensor.abs().max()):.3g}; "
                             f"expected values within +-{max_abs:g}")


def read_safetensors(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Every tensor of the safetensors file ``path`` (torch, on CPU), after bounding the file
    (:data:`MAX_WEIGHTS_BYTES`), its header (:data:`MAX_HEADER_BYTES`, read after its 8-byte length), the count of
    tensors (:data:`MAX_TENSORS`), their dtypes (:data:`TENSOR_DTYPES`) and sizes, and checking that every value
    is finite and at most :data:`MAX_ABS_WEIGHT` in magnitude. Raises ``FileNotFoundError`` for a missing file and
    ``ValueError`` (one line naming the file) for a bad one."""
    from safetensors.torch import load

    name = shown(path)
    data = read_bounded(path, MAX_WEIGHTS_BYTES, "weights file")
    _safetensors_header(data, name)
    try:
        tensors = load(data)
    except Exception as exc:  # noqa: BLE001 - safetensors raises its own error types; all mean "bad file"
        text = printable(" ".join(str(exc).split()) or type(exc).__name__, 200)
        raise ValueError(f"{name}: not a readable safetensors file, truncated or corrupt ({text})") from None
    _finite(name, tensors, MAX_ABS_WEIGHT)
    return tensors


def read_checkpoint_tensors(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Every tensor of a training checkpoint's ``state.safetensors`` (torch, on CPU), read within bounds: a regular
    file of at most :data:`MAX_CHECKPOINT_BYTES`; its header read first (its length, then at most
    :data:`MAX_HEADER_BYTES`), listing at most :data:`MAX_CHECKPOINT_TENSORS` tensors of the
    :data:`CHECKPOINT_DTYPES`, each at most :data:`MAX_CHECKPOINT_VALUES` values; the tensors' bytes must fill the
    file exactly; then the file is mapped (not copied twice) and every floating-point value must be finite.
    A checkpoint is larger than a policy (optimizer state, the pending rollout, generators), so its bounds are
    wider, but still bound the memory a resume takes to the file's size. Raises ``FileNotFoundError`` or
    ``ValueError`` (one line naming the file)."""
    from safetensors.torch import load_file

    name = shown(path)
    with _refusals(path, MAX_CHECKPOINT_BYTES, "checkpoint"), reading.open_regular(path, MAX_CHECKPOINT_BYTES) as (
            handle, size):
        head = handle.read(8)  # the header's length, then the header: never more than MAX_HEADER_BYTES
        length = int.from_bytes(head, "little") if len(head) == 8 else 0
        if length <= MAX_HEADER_BYTES:
            head += handle.read(length)
    entries = _safetensors_header(head, name, CHECKPOINT_DTYPES, MAX_CHECKPOINT_TENSORS, MAX_CHECKPOINT_VALUES,
                                  "a checkpoint")
    expected = 0
    for key, entry in entries.items():
        offsets = entry.get("data_offsets")
        width = CHECKPOINT_DTYPES[entry["dtype"]]
        if (not isinstance(offsets, list) or len(offsets) != 2 or not all(type(n) is int for n in offsets)
                or offsets[1] - offsets[0] != width * math.prod(entry["shape"]) or offsets[0] < 0):
            raise ValueError(f"{name}: tensor {clip_repr(key)}: data_offsets {clip_repr(offsets)} do not match its "
                             "dtype and shape; truncated or corrupt")
        expected += offsets[1] - offsets[0]
    if 8 + length + expected != size:
        raise ValueError(f"{name}: {size:,} bytes where its header describes {8 + length + expected:,}; truncated or "
                         "corrupt")
    try:
        tensors = load_file(os.fspath(path), device="cpu")
    except Exception as exc:  # noqa: BLE001 - safetensors raises its own error types; all mean "bad file"
        text = printable(" ".join(str(exc).split()) or type(exc).__name__, 200)
        raise ValueError(f"{name}: not a readable safetensors file, truncated or corrupt ({text})") from None
    _finite(name, tensors, math.inf)
    return tensors


# --------------------------------------------------------------------------- descriptions


def json_object(value: Any, where: str) -> dict[str, Any]:
    """``value`` if it is a JSON object, else a ``ValueError`` naming ``where``."""
    if not isinstance(value, dict):
        raise ValueError(f"{where}: expected a JSON object, got {clip_repr(value)}")
    return value


def get(obj: Any, key: str, where: str) -> Any:
    """``obj[key]`` of the JSON object ``obj`` (found at ``where``; ``""`` for the document); a ``ValueError`` naming
    the key if ``obj`` is not an object or has no ``key``."""
    json_object(obj, where or "the description")
    if key not in obj:
        raise ValueError(f"{where + '.' if where else ''}{key}: missing")
    return obj[key]


def number(value: Any, where: str, low: float = -math.inf, high: float = math.inf, *, above: bool = False) -> float:
    """``value`` as a float: an ``int`` or ``float`` (not a bool), finite, ``>= low`` (``> low`` with ``above``) and
    ``<= high``; else a ``ValueError`` naming ``where``."""
    ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    x = math.nan
    if ok:
        try:
            x = float(value)
        except OverflowError:  # an integer beyond any float
            ok = False
    ok = ok and math.isfinite(x) and (x > low if above else x >= low) and x <= high
    if not ok:
        span = ("" if low == -math.inf and high == math.inf else f" {'>' if above else '>='} {low:g}"
                if high == math.inf else f" in {'(' if above else '['}{low:g}, {high:g}]")
        raise ValueError(f"{where}: expected a finite number{span}, got {clip_repr(value)}")
    return x


def integer(value: Any, where: str, low: int, high: int) -> int:
    """``value`` if it is an ``int`` (not a bool) in ``[low, high]``, else a ``ValueError`` naming ``where``."""
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        span = f"{low}" if low == high else f"an integer in {low}-{high}"
        raise ValueError(f"{where}: expected {span}, got {clip_repr(value)}")
    return value


def widths(value: Any, where: str, min_layers: int = 1, max_layers: int = MAX_DEPTH) -> tuple[int, ...]:
    """Hidden layer widths: a list of ``min_layers``-``max_layers`` integers in 1-:data:`MAX_WIDTH`."""
    if (not isinstance(value, list) or not min_layers <= len(value) <= max_layers
            or not all(type(h) is int and 1 <= h <= MAX_WIDTH for h in value)):
        raise ValueError(f"{where}: expected a list of {min_layers}-{max_layers} layer widths; widths must be integers "
                         f"in 1-{MAX_WIDTH}, got {clip_repr(value)}")
    return tuple(value)


def vector(value: Any, where: str, min_len: int = 1, max_len: int = MAX_INPUTS, low: float = -math.inf
           ) -> np.ndarray:
    """A list of ``min_len``-``max_len`` finite numbers (each ``>= low``; no bools, lists or objects) as float64."""
    if not isinstance(value, list) or not min_len <= len(value) <= max_len:
        size = f"{len(value):,} values" if isinstance(value, list) else clip_repr(value)
        raise ValueError(f"{where}: expected a list of {min_len}-{max_len} numbers, got {size}")
    for i, v in enumerate(value):
        number(v, f"{where}[{i}]", low)
    return np.asarray(value, dtype=np.float64)


def statistics(d: Any, where: str, size: int | None = None, max_len: int = MAX_INPUTS, *, clip_key: str = "clip",
               need_clip: bool = True) -> int:
    """Check normalisation statistics ``{"mean", "var", "count", "epsilon", clip_key}`` (a ``RunningMeanStd`` or
    SB3's ``VecNormalize`` as JSON): ``mean`` and ``var`` lists of the same 1-``max_len`` finite numbers (``size``
    of them when given), ``var >= 0``, ``count`` finite ``>= 0``, ``epsilon`` and ``clip`` finite ``> 0``. Returns the
    size."""
    mean = vector(get(d, "mean", where), f"{where}.mean", max_len=max_len)
    var = vector(get(d, "var", where), f"{where}.var", max_len=max_len, low=0.0)
    if len(var) != len(mean):
        raise ValueError(f"{where}.var: expected {len(mean)} values (as many as mean), got {len(var)}")
    if size is not None and len(mean) != size:
        raise ValueError(f"{where}.mean: expected {size} values, got {len(mean)}")
    number(get(d, "count", where), f"{where}.count", 0.0)
    number(get(d, "epsilon", where), f"{where}.epsilon", 0.0, 1.0, above=True)
    if need_clip:
        number(get(d, clip_key, where), f"{where}.{clip_key}", 0.0, MAX_CLIP, above=True)
    return len(mean)


def spec(value: Any, where: str) -> str:
    """A policy spec named by a description: a non-empty string of at most :data:`MAX_SPEC_CHARS` visible
    characters."""
    if not isinstance(value, str) or not 0 < len(value) <= MAX_SPEC_CHARS or printable(value) != value:
        raise ValueError(f"{where}: expected a policy spec (1-{MAX_SPEC_CHARS} printable characters), got "
                         f"{clip_repr(value)}")
    return value


def mlp_parameters(sizes: Sequence[int]) -> int:
    """Parameters of ``swarm_env_baselines.ppo_core.mlp(sizes)``: a weight matrix and a bias per layer."""
    return sum(a * b + b for a, b in zip(sizes[:-1], sizes[1:]))


def check_parameters(count: int, where: str, what: str = "the network") -> None:
    """A ``ValueError`` naming ``where`` if ``count`` (a network's parameters) is over :data:`MAX_PARAMETERS`."""
    if count > MAX_PARAMETERS:
        raise ValueError(f"{where}: {what} would have {count:,} parameters, more than {MAX_PARAMETERS:,}; refused "
                         "before building it")
