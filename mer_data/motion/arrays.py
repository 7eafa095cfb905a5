"""NumPy ``.npz`` / ``.npy`` files read without pickles and within bounded memory.

What SMPL-family motions, body models and joint-position arrays are read through. Every array's
header (dtype and shape) is read before its data: object arrays (pickles) are refused, and the
declared sizes of all arrays together must stay under ``MER_MAX_ARRAY_BYTES``, so a hostile header
or a zip bomb is refused before it is allocated. Arrays are then read with ``allow_pickle=False``.
Pickled files (``.pkl``, or pickle bytes under another name) are refused with ``pickle_fix``.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from mer_data.base.errors import MotionFormatError
from mer_data.base.limits import limit, too_big
from mer_data.base.safe_io import check_regular_file

__all__ = ["read_arrays", "PICKLE_MAGIC"]

#: First byte of a pickle of protocol 2 or later.
PICKLE_MAGIC = b"\x80"


def _header(f, path: Path, name: str, error) -> tuple[np.dtype, tuple[int, ...]]:
    try:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(f)
        else:
            shape, _, dtype = np.lib.format.read_array_header_2_0(f)
    except (ValueError, OSError, SyntaxError, EOFError) as exc:
        raise error(f"array {name!r} is not a NumPy array ({str(exc)[:200]})", path=path, element=name,
                    fix="write it with numpy.save / numpy.savez") from None  # fmt: skip
    if dtype.hasobject:
        raise error(f"array {name!r} holds Python objects (a pickle); mer reads plain numeric arrays only",
                    path=path, element=name, fix="save plain arrays: np.savez(path, key=np.asarray(value, float))")  # fmt: skip
    return dtype, tuple(int(s) for s in shape)


def read_arrays(path: str | Path, *, error: type[MotionFormatError] = MotionFormatError, pickle_fix: str,
                keys: set[str] | None = None) -> dict[str, np.ndarray]:  # fmt: skip
    """The arrays of an ``.npz`` (name -> array) or an ``.npy`` (``{"arr_0": array}``).

    Args:
        path: the file; error: the error class raised; pickle_fix: what to do instead of a pickle.
        keys: read only these members of an npz (the others' headers are still checked).

    Raises:
        error: not an npz/npy, a pickle, an object array, sizes over ``MER_MAX_ARRAY_BYTES``.
    """
    path = Path(path)
    st = check_regular_file(path, error)
    cap = limit("MER_MAX_ARRAY_BYTES")
    if st.st_size > cap:
        msg, how = too_big("MER_MAX_ARRAY_BYTES", st.st_size)
        raise error(msg, path=path, fix=how)
    with open(path, "rb") as f:
        head = f.read(8)
    if path.suffix.lower() in (".pkl", ".pickle", ".p") or head[:1] == PICKLE_MAGIC:
        raise error("is a Python pickle; mer never unpickles a file (it could run code)", path=path, fix=pickle_fix)
    if head.startswith(b"PK"):
        return _read_npz(path, error, cap, keys)
    if head.startswith(b"\x93NUMPY"):
        with open(path, "rb") as f:
            dtype, shape = _header(f, path, "arr_0", error)
            if int(np.prod(shape, dtype=np.float64)) * dtype.itemsize > cap:
                msg, how = too_big("MER_MAX_ARRAY_BYTES", f"{int(np.prod(shape, dtype=np.float64)) * dtype.itemsize:,}")
                raise error(msg, path=path, fix=how)
        try:
            return {"arr_0": np.load(path, allow_pickle=False)}
        except (ValueError, OSError, EOFError) as exc:
            raise error(f"cannot read the array ({str(exc)[:200]})", path=path, fix="write it again with numpy.save") from None
    from mer_data.base.sniff import describe

    raise error(f"is not a NumPy .npz or .npy file ({describe(head)})", path=path,
                fix="give the .npz / .npy file itself (numpy.savez writes an npz)")  # fmt: skip


def _read_npz(path: Path, error, cap: int, keys: set[str] | None) -> dict[str, np.ndarray]:
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        raise error(f"is not a readable .npz (zip) file ({str(exc)[:200]})", path=path,
                    fix="write it again with numpy.savez") from None  # fmt: skip
    out: dict[str, np.ndarray] = {}
    with zf:
        infos = [i for i in zf.infolist() if i.filename.endswith(".npy")]
        if len(zf.infolist()) > 10_000:
            raise error(f"the npz holds {len(zf.infolist())} members", path=path, fix="write a plain numpy.savez file")
        total = 0
        wanted = []
        for info in infos:
            name = info.filename[: -len(".npy")]
            try:
                with zf.open(info) as f:
                    dtype, shape = _header(f, path, name, error)
            except (zipfile.BadZipFile, OSError, RuntimeError, NotImplementedError) as exc:
                raise error(f"member {name!r} cannot be read ({str(exc)[:200]})", path=path, element=name,
                            fix="write it again with numpy.savez") from None  # fmt: skip
            if keys is not None and name not in keys:
                continue
            total += int(np.prod(shape, dtype=np.float64)) * dtype.itemsize
            if total > cap:
                msg, how = too_big("MER_MAX_ARRAY_BYTES", f"over {total:,}")
                raise error(msg, path=path, fix=how)
            wanted.append((info, name))
        for info, name in wanted:
            try:
                with zf.open(info) as f:
                    out[name] = np.lib.format.read_array(f, allow_pickle=False)
            except (ValueError, OSError, EOFError, zipfile.BadZipFile, RuntimeError) as exc:
                raise error(f"member {name!r} cannot be read ({str(exc)[:200]})", path=path, element=name,
                            fix="write it again with numpy.savez") from None  # fmt: skip
    return out
