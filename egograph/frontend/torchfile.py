"""A reader for torch's *legacy* (non-zip) serialisation, without torch.

Layout of such a file: five pickles in a row -- the magic number, the protocol version, a
``sys_info`` dict (byte order, type sizes), the object itself (here a state dict) whose tensors
refer to storages by *persistent id* ``("storage", StorageType, key, location, numel)``, and the
list of storage keys in the order their bytes follow -- then, per key, an int64 element count and
the raw little-endian element bytes. Tensors are rebuilt as numpy views (offset, size and stride
in elements), so a state dict comes back as ``{name: np.ndarray}``.
"""

from __future__ import annotations

import collections
import pickle
import struct
from pathlib import Path

import numpy as np

from egograph.core.errors import InputError

MAGIC = 0x1950A86A20F9469CFC6C
PROTOCOL = 1001

STORAGE_DTYPES = {
    "FloatStorage": np.float32, "DoubleStorage": np.float64, "HalfStorage": np.float16,
    "LongStorage": np.int64, "IntStorage": np.int32, "ShortStorage": np.int16,
    "CharStorage": np.int8, "ByteStorage": np.uint8, "BoolStorage": np.bool_,
}


class _StorageType:
    def __init__(self, name: str):
        self.name = name
        self.dtype = np.dtype(STORAGE_DTYPES[name])


class _TensorRef:
    """A tensor waiting for its storage bytes: ``(storage key, offset, size, stride)`` in elements."""

    def __init__(self, storage, offset, size, stride):
        self.storage, self.offset, self.size, self.stride = storage, int(offset), tuple(size), tuple(stride)


def _rebuild_tensor_v2(storage, storage_offset, size, stride, *_ignored):
    return _TensorRef(storage, storage_offset, size, stride)


def _rebuild_parameter(data, *_ignored):
    return data


class _Unpickler(pickle.Unpickler):
    """Maps the few torch globals a state dict needs; anything else is refused (no code runs)."""

    def __init__(self, file, path: Path):
        super().__init__(file)
        self.path = path
        self.storages: dict[str, tuple[np.dtype, int]] = {}

    def find_class(self, module, name):
        if (module, name) == ("collections", "OrderedDict"):
            return collections.OrderedDict
        if module == "torch._utils" and name == "_rebuild_tensor_v2":
            return _rebuild_tensor_v2
        if module == "torch._utils" and name == "_rebuild_parameter":
            return _rebuild_parameter
        if module == "torch" and name in STORAGE_DTYPES:
            return _StorageType(name)
        raise InputError(self.path, f"not a plain torch state dict: it refers to {module}.{name}")

    def persistent_load(self, pid):
        if not (isinstance(pid, tuple) and len(pid) >= 5 and pid[0] == "storage"):
            raise InputError(self.path, f"unknown persistent id {pid!r:.80}")
        stype, key, numel = pid[1], str(pid[2]), int(pid[4])
        self.storages[key] = (stype.dtype, numel)
        return key


def read_legacy_state_dict(path: str | Path) -> dict[str, np.ndarray]:
    """``{name: array}`` of a torch legacy-format state dict file (float32 weights stay float32)."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            return _read(f, path)
    except OSError as e:
        raise InputError(path, f"cannot read: {e.strerror or e}") from e
    except (pickle.UnpicklingError, EOFError, struct.error, ValueError, KeyError, AttributeError, TypeError) as e:
        if isinstance(e, InputError):
            raise
        raise InputError(path, f"not a torch legacy-format file ({type(e).__name__}: {e})") from e


def _read(f, path: Path) -> dict[str, np.ndarray]:
    up = _Unpickler(f, path)
    if up.load() != MAGIC:
        raise InputError(path, "not a torch legacy-format file (no magic number; zip-format files are not read)")
    if up.load() != PROTOCOL:
        raise InputError(path, "unsupported torch legacy protocol version")
    info = up.load()
    if not info.get("little_endian", True):
        raise InputError(path, "big-endian torch file")
    obj = up.load()
    keys = [str(k) for k in up.load()]
    arrays = {}
    for key in keys:
        (numel,) = struct.unpack("<q", f.read(8))
        dtype, expect = up.storages[key]
        data = f.read(numel * dtype.itemsize)
        if len(data) != numel * dtype.itemsize or numel != expect:
            raise InputError(path, f"truncated storage {key}")
        arrays[key] = np.frombuffer(data, dtype=dtype)
    if not isinstance(obj, dict):
        raise InputError(path, f"holds a {type(obj).__name__}, not a state dict")
    out = {}
    for name, ref in obj.items():
        if not isinstance(ref, _TensorRef):
            continue
        flat = arrays[ref.storage]
        item = flat.itemsize
        view = np.lib.stride_tricks.as_strided(flat[ref.offset:], shape=ref.size,
                                               strides=tuple(s * item for s in ref.stride), writeable=False)
        out[name] = np.ascontiguousarray(view)
    return out
