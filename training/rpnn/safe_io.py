"""One way to open a file for reading, for every reader of the training scripts (the Python
side of ``crates/scene/src/fsio.rs`` and ``memory.rs``).

- The file is opened without blocking (``O_NONBLOCK``: opening a named pipe would wait for a
  writer that may never come) and checked on the opened descriptor (``fstat``): anything but a
  regular file (a pipe, a socket, a device such as ``/dev/zero``, a folder) is refused at once.
- Symbolic links are followed; a loop or a dangling link is said as such.
- Its size is checked against the memory budget before a byte is read, and whole-file reads
  stop at the size ``fstat`` gave. The budget: ``--max-memory`` (:func:`set_budget`), else
  ``NIMBUS_MAX_MEMORY`` (``6G``, ``512M``, ``1.5GiB``, bytes), else 3/4 of the physical memory
  or of the cgroup limit when that is lower: the same rule as the renderer's.
- Every failure is an :class:`InputError` whose message is ``<path>: <what>``; the scripts' main
  functions print it as one line ``error: <path>: <what>`` and exit with status 2
  (:func:`reporting_input_errors`).
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import io
import json
import os
import stat
import sys
from pathlib import Path

ENV = "NIMBUS_MAX_MEMORY"
# Fallback when the physical memory cannot be read (as the renderer's).
FALLBACK = 8 << 30

_budget: int | None = None


class InputError(ValueError):
    """A file or value that cannot be used; the message names the file (or flag) and says what
    is wrong with it."""

    def __init__(self, message: str, missing: bool = False):
        super().__init__(message)
        # Nothing at the path (no file, no link): callers may say how to make it.
        self.missing = missing


class InputExit(SystemExit):
    """Exit status 2 after the error line was printed; ``str()`` is that line (so that a caller
    of a script's ``main`` sees the message)."""

    def __init__(self, message: str):
        super().__init__(2)
        self.message = message

    def __str__(self) -> str:
        return self.message


@contextlib.contextmanager
def reporting_input_errors():
    """Turns an :class:`InputError` into one line ``error: <message>`` on stderr and exit
    status 2 (no traceback)."""
    try:
        yield
    except InputError as e:
        line = f"error: {e}"
        print(line, file=sys.stderr, flush=True)
        raise InputExit(line) from None


def parse_size(s: str) -> int:
    """A size: bytes, or a number with K, M, G, T (powers of 1024; ``KB``, ``KiB`` alike)."""
    t = str(s).strip()
    split = next((i for i, c in enumerate(t) if not (c.isdigit() or c == ".")), len(t))
    num, unit = t[:split], t[split:].strip().upper()
    shifts = {"": 0, "B": 0, "K": 10, "KB": 10, "KIB": 10, "M": 20, "MB": 20, "MIB": 20,
              "G": 30, "GB": 30, "GIB": 30, "T": 40, "TB": 40, "TIB": 40}
    try:
        v = float(num)
    except ValueError:
        raise ValueError(f"`{s}`: expected a size such as 6G, 512M or 1000000") from None
    if unit not in shifts:
        raise ValueError(f"`{s}`: unknown unit `{unit}` (K, M, G or T)")
    b = v * float(1 << shifts[unit])
    if not b >= 1.0:
        raise ValueError(f"`{s}`: must be at least 1 byte")
    if not b < 2.0**64:
        raise ValueError(f"`{s}`: too large (at most 16 EiB, 2^64 bytes)")
    return int(b)


def human(n: int) -> str:
    """A size for people: ``8.0 GiB``."""
    k = 1024.0
    for p, name in ((4, "TiB"), (3, "GiB"), (2, "MiB"), (1, "KiB")):
        if n >= k**p:
            return f"{n / k**p:.1f} {name}"
    return f"{n} bytes"


def default_budget() -> int:
    """3/4 of the physical memory, or of the cgroup (v2) limit when that is lower."""
    total = FALLBACK // 3 * 4
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemTotal:"):
                    total = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        pass
    try:
        with open("/sys/fs/cgroup/memory.max") as f:
            total = min(total, int(f.read().strip()))
    except (OSError, ValueError):  # absent, or "max"
        pass
    return total // 4 * 3


def set_budget(n: int | None) -> None:
    """Sets the budget for this process (a script's ``--max-memory``; None: the default rule)."""
    global _budget
    _budget = None if n is None else max(int(n), 1)


def budget() -> int:
    """The memory budget in bytes: :func:`set_budget`, else ``NIMBUS_MAX_MEMORY``, else
    :func:`default_budget`. A ``NIMBUS_MAX_MEMORY`` that is no size is an error naming it."""
    if _budget is not None:
        return _budget
    v = os.environ.get(ENV)
    if v is not None and v.strip():
        try:
            return parse_size(v)
        except ValueError as e:
            raise InputError(f"{ENV}={v}: {e}") from None
    return default_budget()


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a named pipe (FIFO)"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    return "not a regular file"


def os_error(path, e: OSError) -> InputError:
    """An OSError of ``path`` as an InputError, with the cases users meet said in words."""
    path = Path(path)
    if e.errno == errno.ELOOP:
        return InputError(f"{path}: a symbolic link that loops (too many levels of links)")
    if e.errno in (errno.ENOENT, errno.ENOTDIR):
        try:
            if stat.S_ISLNK(os.lstat(path).st_mode):
                try:
                    to = os.readlink(path)
                except OSError:
                    to = "?"
                return InputError(f"{path}: a symbolic link to nothing (dangling link to {to})")
        except OSError:
            pass
        return InputError(f"{path}: no such file", missing=True)
    try:
        # e.g. ENXIO: a socket cannot be opened at all; say what it is.
        mode = os.stat(path).st_mode
        if not stat.S_ISREG(mode):
            return InputError(f"{path}: {_kind(mode)}, expected a file to read")
    except OSError:
        pass
    return InputError(f"{path}: cannot be read ({e.strerror or e})")


def open_regular(path, max_bytes: int | None = None, what: str = "a file to read"):
    """Opens ``path`` for reading: a regular file (links followed), without waiting on a pipe,
    no larger than ``max_bytes`` (default: the memory budget). Returns ``(file, size)``: a
    binary file object positioned at 0 (the caller closes it) and the size ``fstat`` gave."""
    path = Path(path)
    limit = budget() if max_bytes is None else max_bytes
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | getattr(os, "O_CLOEXEC", 0))
    except OSError as e:
        raise os_error(path, e) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise InputError(f"{path}: {_kind(st.st_mode)}, expected {what}")
        if st.st_size > limit:
            raise InputError(f"{path}: {human(st.st_size)}, more than the memory budget of "
                             f"{human(limit)} allows reading (--max-memory or {ENV})")
        # Regular files never block; reads behave as without O_NONBLOCK from here.
        os.set_blocking(fd, True)
        f = os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise
    return f, st.st_size


def check_regular(path, max_bytes: int | None = None, what: str = "a file to read") -> int:
    """The checks of :func:`open_regular` without reading; returns the size."""
    f, size = open_regular(path, max_bytes, what)
    f.close()
    return size


def _read_all(f, size: int, path: Path) -> bytes:
    """At most ``size`` bytes (the size at open: a growing file cannot make this unbounded)."""
    try:
        data = f.read(size)
    except MemoryError:
        raise InputError(f"{path}: cannot allocate {human(size)} to read this file") from None
    except OSError as e:
        raise InputError(f"{path}: cannot be read ({e.strerror or e})") from None
    return data


def read_bytes(path, max_bytes: int | None = None, what: str = "a file to read") -> bytes:
    """The whole file (:func:`open_regular`)."""
    path = Path(path)
    f, size = open_regular(path, max_bytes, what)
    with f:
        return _read_all(f, size, path)


def sha256_file(path, max_bytes: int | None = None) -> str:
    """Hex SHA-256 of a file, read in chunks (:func:`open_regular`)."""
    path = Path(path)
    f, _ = open_regular(path, max_bytes)
    with f:
        try:
            return hashlib.file_digest(f, "sha256").hexdigest()
        except OSError as e:
            raise InputError(f"{path}: cannot be read ({e.strerror or e})") from None


def read_text(path, max_bytes: int | None = None, what: str = "a text file") -> str:
    """The whole file as UTF-8 text; other bytes are an error naming the file."""
    path = Path(path)
    data = read_bytes(path, max_bytes, what)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise InputError(f"{path}: not UTF-8 text (byte {e.start} is not valid UTF-8)") from None


def load_json(path, max_bytes: int | None = None, what: str = "a JSON file"):
    """The file's JSON value; text that is not JSON is an error naming the file."""
    path = Path(path)
    data = read_bytes(path, max_bytes, what)
    try:
        return json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise InputError(f"{path}: not valid JSON (byte {e.start} is not UTF-8)") from None
    except (json.JSONDecodeError, RecursionError) as e:
        raise InputError(f"{path}: not valid JSON ({e})") from None


def load_npy(path, mmap: bool = False, max_bytes: int | None = None, digest: bool = False):
    """A ``.npy`` array (never pickled objects). ``mmap``: memory-mapped read-only from the
    opened, checked descriptor (a set larger than memory is not read in full). ``digest``: also
    the file's hex SHA-256, hashed from the same descriptor; returns ``(array, digest)``."""
    import numpy as np

    path = Path(path)
    f, size = open_regular(path, max_bytes, "a .npy file")
    with f:
        sha = None
        if digest:
            try:
                sha = hashlib.file_digest(f, "sha256").hexdigest()
                f.seek(0)
            except OSError as e:
                raise InputError(f"{path}: cannot be read ({e.strerror or e})") from None
        try:
            a = _memmap(f, size, path) if mmap else np.load(f, allow_pickle=False)
        except InputError:
            raise
        except MemoryError:
            raise InputError(f"{path}: cannot allocate memory to read this file") from None
        except (ValueError, EOFError, OverflowError, OSError, TypeError) as e:
            raise InputError(f"{path}: not a readable .npy file ({e})") from None
    if not isinstance(a, np.ndarray):
        raise InputError(f"{path}: not a .npy array")
    return (a, sha) if digest else a


def _memmap(f, size: int, path: Path):
    import numpy as np

    fmt = np.lib.format
    version = fmt.read_magic(f)
    if version == (1, 0):
        shape, fortran, dtype = fmt.read_array_header_1_0(f)
    elif version == (2, 0):
        shape, fortran, dtype = fmt.read_array_header_2_0(f)
    else:
        raise ValueError(f".npy format version {version[0]}.{version[1]} is not read here "
                         f"(1.0 and 2.0 are)")
    if dtype.hasobject:
        raise ValueError("the array holds Python objects (pickles are not loaded)")
    offset = f.tell()
    count = 1
    for d in shape:
        count *= int(d)
    need = count * dtype.itemsize
    if offset + need > size:
        raise ValueError(f"the header says {shape} {dtype} ({need} bytes of data), the file "
                         f"holds {size - offset}: it is truncated")
    if need == 0:
        return np.zeros(shape, dtype=dtype)
    return np.memmap(f, dtype=dtype, mode="r", shape=shape,
                     order="F" if fortran else "C", offset=offset)


def torch_load(path, map_location="cpu", data: bytes | None = None):
    """A checkpoint of the training scripts: its bytes read through :func:`read_bytes` (or
    ``data``, bytes already read), loaded with ``weights_only=True`` (tensors and plain Python
    values; no code runs)."""
    import torch

    if data is None:
        data = read_bytes(path, what="a checkpoint file")
    return torch.load(io.BytesIO(data), map_location=map_location, weights_only=True)
