"""The resource policy: what a load or a render may open, read, inflate and allocate.

Files come from colleagues, archives and downloads, and inside Blender a crash loses the
user's unsaved scene, so every reader and the renderer go through this one module:

- only regular files are opened (never a FIFO, a device such as /dev/zero, a socket or a
  folder), and only the ones the user named or the format itself references;
- compressed data is inflated with its output bounded in advance (`inflate`): a block may
  never grow beyond what its header or the mesh says it holds;
- every large allocation is checked first (`check_bytes`) against one overridable memory
  limit, a ray's march against a limit on samples per ray, and every set of processes a run
  starts (render devices, Dask workers) against a limit on processes (`check_processes`);
  the error names the limit and how to raise it;
- outputs are opened without following a link (`open_output`), so a link planted where an
  output goes can neither redirect it nor create the link's target.

Limits are read from the environment (HOVR_MAX_MEMORY, e.g. "8G"; HOVR_MAX_SAMPLES_PER_RAY;
HOVR_MAX_INFLATE_RATIO; HOVR_MAX_READ_SECONDS, a flat wall time for one read in the reader process
instead of read_seconds' rule; HOVR_MAX_PROCESSES) and can be overridden for a block of code with `using(ResourceLimits(...))`
(the CLI's --max-memory and --max-samples-per-ray do this).
"""
from __future__ import annotations

import contextlib
import contextvars
import errno
import lzma
import os
import re
import stat
import zlib
from dataclasses import dataclass, replace

DEFAULT_MAX_MEMORY = 4 << 30  # bytes of arrays one load or one render may allocate
DEFAULT_MAX_SAMPLES_PER_RAY = 100_000  # fixed-step methods: (data diagonal) / h at most
# Compressed data may inflate to this many times the file's size (real solver output compresses
# by < 10x; a zlib bomb by ~1000x), and always to INFLATE_FLOOR: a small file whose declared
# sizes agree with each other is still refused when they are far beyond what its bytes can hold.
DEFAULT_MAX_INFLATE_RATIO = 100
INFLATE_FLOOR = 64 << 20
# One read in the reader process (io/isolation.py) may use READ_BASE_SECONDS plus
# READ_SECONDS_PER_MB of processor time for each MB (10^6 bytes) of the files it opens, and is
# stopped when it uses READ_STALL_SECONDS of processor time without progress (libhdf5 loops without
# end on some damaged files). Processor time, because a loaded machine stretches an honest read's
# wall time (scaleHO: 4.4 s at load 6, more than 13 s at load 10, on this 2-core machine; 4.5 s
# between two progress reports at load 9) but not its processor time (scaleHO 0.65 s a MB, 0.23 s
# at most between two reports). Measured: bench/read_rate.py, docs/limits.md has the table.
READ_BASE_SECONDS = 5.0
READ_SECONDS_PER_MB = 2.0
READ_STALL_SECONDS = 2.0


def cpu_cores() -> int:
    """The CPU cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


CPU_THREADS_VARIABLE = "HOVR_CPU_THREADS"


def cpu_threads() -> int:
    """Threads one CPU render may run its launch tiles on (Warp runs a CPU launch on the thread
    that makes it, without Python's lock): HOVR_CPU_THREADS where set (1: one core), else every
    core this process may use."""
    value = os.environ.get(CPU_THREADS_VARIABLE, "").strip()
    if value:
        try:
            return max(1, int(value))
        except ValueError:
            raise ResourceLimitError(f"{CPU_THREADS_VARIABLE}={value!r}: a whole number of threads, 1 or more") from None
    return cpu_cores()


def default_max_processes() -> int:
    """Processes one run may start (render devices, Dask workers): one a core this process may
    use, and at least 2 (a two-device split on a one-core machine); a process holds its own copy
    of the mesh, so more than the cores only multiplies memory."""
    return max(2, cpu_cores())


class ResourceLimitError(ValueError):
    """Input refused by the resource policy; the message names the limit and how to raise it."""


class UnsafeFileError(ValueError):
    """A path that is not a regular file (FIFO, device, socket, folder) or a reference the
    policy refuses (HDF5 external storage, links to other files)."""


def parse_size(text) -> int:
    """'4G', '512M', '1.5G', '1000000' -> bytes."""
    m = re.fullmatch(r"\s*([0-9]*\.?[0-9]+)\s*([kKmMgGtT]?)(i?[bB])?\s*", str(text))
    if m is None:
        raise ValueError(f"size {text!r}: write a number of bytes, optionally with K, M, G or T")
    scale = {"": 1, "k": 1 << 10, "m": 1 << 20, "g": 1 << 30, "t": 1 << 40}[m.group(2).lower()]
    value = int(float(m.group(1)) * scale)
    if value <= 0:
        raise ValueError(f"size {text!r} must be positive")
    return value


def format_size(n: int) -> str:
    for unit, scale in (("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n} bytes"


@dataclass(frozen=True)
class ResourceLimits:
    max_memory: int = DEFAULT_MAX_MEMORY
    max_samples_per_ray: int = DEFAULT_MAX_SAMPLES_PER_RAY
    max_inflate_ratio: int = DEFAULT_MAX_INFLATE_RATIO
    max_read_seconds: float | None = None  # a flat limit a read (HOVR_MAX_READ_SECONDS); None: read_seconds
    max_processes: int = 0  # 0: default_max_processes() of the machine it runs on

    def __post_init__(self):
        if int(self.max_memory) <= 0 or int(self.max_samples_per_ray) <= 0 or int(self.max_inflate_ratio) <= 0 \
                or int(self.max_processes) < 0:
            raise ValueError("resource limits must be positive")
        if self.max_read_seconds is not None and not float(self.max_read_seconds) > 0:
            raise ValueError("resource limits must be positive")

    @classmethod
    def from_environment(cls) -> "ResourceLimits":
        out = cls()
        if os.environ.get("HOVR_MAX_MEMORY"):
            out = replace(out, max_memory=parse_size(os.environ["HOVR_MAX_MEMORY"]))
        if os.environ.get("HOVR_MAX_SAMPLES_PER_RAY"):
            out = replace(out, max_samples_per_ray=int(float(os.environ["HOVR_MAX_SAMPLES_PER_RAY"])))
        if os.environ.get("HOVR_MAX_INFLATE_RATIO"):
            out = replace(out, max_inflate_ratio=int(float(os.environ["HOVR_MAX_INFLATE_RATIO"])))
        if os.environ.get("HOVR_MAX_READ_SECONDS"):
            out = replace(out, max_read_seconds=float(os.environ["HOVR_MAX_READ_SECONDS"]))
        if os.environ.get("HOVR_MAX_PROCESSES"):
            try:
                n = int(os.environ["HOVR_MAX_PROCESSES"])
            except ValueError:
                raise ValueError(f"HOVR_MAX_PROCESSES={os.environ['HOVR_MAX_PROCESSES']!r} is not a whole number") from None
            if n <= 0:
                raise ValueError(f"HOVR_MAX_PROCESSES={n} must be at least 1")
            out = replace(out, max_processes=n)
        return out


_CURRENT: contextvars.ContextVar = contextvars.ContextVar("hovr_limits", default=None)


def current() -> ResourceLimits:
    lim = _CURRENT.get()
    return lim if lim is not None else ResourceLimits.from_environment()


@contextlib.contextmanager
def using(limits: ResourceLimits):
    """Apply `limits` to every load and render inside the block."""
    token = _CURRENT.set(limits)
    try:
        yield limits
    finally:
        _CURRENT.reset(token)


def read_seconds(nbytes: int, cap: float | None = None, limits: ResourceLimits | None = None) -> float:
    """The time one read of files of `nbytes` in all may take: the flat limit where one is set
    (HOVR_MAX_READ_SECONDS: wall time), else READ_BASE_SECONDS + READ_SECONDS_PER_MB a MB of
    processor time; at most `cap`."""
    flat = (limits or current()).max_read_seconds
    seconds = float(flat) if flat is not None else READ_BASE_SECONDS + READ_SECONDS_PER_MB * max(0, nbytes) / 1e6
    return seconds if cap is None else min(seconds, float(cap))


def read_stall_seconds(limits: ResourceLimits | None = None) -> float | None:
    """How long a read may make no progress (progress()) before it is stopped; None under a flat
    limit (the user's HOVR_MAX_READ_SECONDS for a genuine file a library reads in one long call)."""
    return READ_STALL_SECONDS if (limits or current()).max_read_seconds is None else None


_PROGRESS = 0


def progress():
    """Reading moves on (a file opened, a block inflated, a batch of elements parsed or checked):
    the reader process reports that its count changed (io/reader_process.py), and a read whose
    count stands still for READ_STALL_SECONDS is stopped. Costs an increment."""
    global _PROGRESS
    _PROGRESS += 1


def progress_count() -> int:
    return _PROGRESS


def check_bytes(nbytes, what: str) -> int:
    """Refuse an allocation of `nbytes` for `what` beyond the memory limit, before it is made."""
    progress()
    limit = current().max_memory
    if not nbytes <= limit:  # also refuses NaN
        raise ResourceLimitError(
            f"{what} would need {format_size(int(nbytes)) if nbytes == nbytes else nbytes}, more than "
            f"the memory limit of {format_size(limit)} (raise it with --max-memory or HOVR_MAX_MEMORY)")
    return int(nbytes)


def check_samples_per_ray(h: float, diagonal: float) -> float:
    """Refuse a fixed step h that would take more samples than the limit on a ray across data
    whose bounding box has this diagonal. Returns the samples it may take."""
    lim = current()
    steps = float(diagonal) / float(h)
    if not steps <= lim.max_samples_per_ray:
        raise ResourceLimitError(
            f"step h = {h:g} would take up to {steps:.3g} samples per ray across the data "
            f"(its bounding box diagonal is {diagonal:.4g}); the limit is "
            f"{lim.max_samples_per_ray} samples per ray (raise it with --max-samples-per-ray or "
            f"HOVR_MAX_SAMPLES_PER_RAY, or use a larger h, or the split method, which needs no h)")
    return steps


def check_processes(n: int, what: str) -> int:
    """Refuse starting `n` processes for `what` beyond the process limit, before any starts."""
    limit = current().max_processes or default_max_processes()
    if not 0 <= n <= limit:
        source = "HOVR_MAX_PROCESSES" if current().max_processes else "one a CPU core here"
        raise ResourceLimitError(
            f"{what} would start {n} processes, more than the limit of {limit} processes a run may start "
            f"({source}; each holds its own copy of the data: raise it with HOVR_MAX_PROCESSES)")
    return int(n)


# ------------------------------------------------------------------------------ files

def _describe(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def check_regular(path, what: str = "data file") -> os.stat_result:
    """stat of `path`, which must be an existing regular file (links are followed)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise FileNotFoundError(f"{what} not found: {path}") from None
    except OSError as exc:
        raise UnsafeFileError(f"{what} {path}: cannot be read ({exc.strerror or exc})") from None
    if not stat.S_ISREG(st.st_mode):
        raise UnsafeFileError(f"{what} {path} is {_describe(st.st_mode)}, not a regular file; refused")
    return st


# Called with (path, what) before each file is opened: the reader process reports its progress
# (and the file a crash happened in) through this (io/reader_process.py).
OPEN_OBSERVERS: list = []


def open_regular(path, what: str = "data file"):
    """A binary file object for a regular file. Opened without blocking and checked on the open
    descriptor, so a FIFO swapped in after a check cannot hold the process."""
    progress()
    for observe in OPEN_OBSERVERS:
        observe(path, what)
    check_regular(path, what)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0))
    except OSError as exc:
        raise UnsafeFileError(f"{what} {path}: cannot be opened ({exc.strerror or exc})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise UnsafeFileError(f"{what} {path} is {_describe(st.st_mode)}, not a regular file; refused")
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_regular(path, what: str = "data file", max_bytes: int | None = None) -> bytes:
    """The whole content of a regular file, its size (fstat of the open file, before a byte is
    read) checked against `max_bytes` (the format's own cap) and the memory limit first."""
    with open_regular(path, what) as fh:
        size = os.fstat(fh.fileno()).st_size
        if max_bytes is not None and size > max_bytes:
            raise ResourceLimitError(f"{what} {path} is {format_size(size)}; at most {format_size(max_bytes)} "
                                     f"is accepted")
        check_bytes(size, f"reading {what} {path}")
        try:
            data = fh.read(size + 1)
        except OSError as exc:  # a regular file that cannot be read: /proc/self/mem
            raise UnsafeFileError(f"{what} {path}: cannot be read ({exc.strerror or exc})") from None
    if len(data) > size:
        raise UnsafeFileError(f"{what} {path} grew while it was read; refused")
    return data


def open_output(path, what: str = "output", append: bool = False):
    """A binary file object writing (or appending to) `path`, never through a link: O_NOFOLLOW
    refuses a symbolic link at `path` (a planted one would redirect the write, and a dangling one
    would create its target), and a FIFO, device or folder there is refused without blocking."""
    flags = os.O_WRONLY | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0) \
        | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0) | (os.O_APPEND if append else 0)
    try:
        fd = os.open(path, flags, 0o644)
    except OSError as exc:
        if os.path.islink(path):
            raise UnsafeFileError(f"{what} {path} is a symbolic link; refused (outputs never follow links)") from None
        if exc.errno == errno.ENXIO:  # a FIFO without a reader
            raise UnsafeFileError(f"{what} {path} is a FIFO (named pipe), not a regular file; refused") from None
        raise UnsafeFileError(f"{what} {path}: cannot be written ({exc.strerror or exc})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise UnsafeFileError(f"{what} {path} is {_describe(st.st_mode)}, not a regular file; refused")
        os.set_blocking(fd, True)
        if not append:
            os.ftruncate(fd, 0)
        return os.fdopen(fd, "ab" if append else "wb")
    except BaseException:
        os.close(fd)
        raise


# ------------------------------------------------------------------------------ inflating

# A process whose address space this module may cap (the reader process sets it: capping
# Blender's or the command's own would fail allocations of other threads).
_ADDRESS_SPACE_OWNED = False


def own_address_space():
    """This process is a reader process: its address space may be capped (cap_address_space,
    small_allocations)."""
    global _ADDRESS_SPACE_OWNED
    _ADDRESS_SPACE_OWNED = True


def address_space() -> int | None:
    """This process's address space now, in bytes (Linux), else None."""
    try:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return None


def cap_address_space(extra: int) -> int | None:
    """Let the address space grow by at most `extra` bytes from now (RLIMIT_AS's soft limit, in a
    process that owns its address space); returns the soft limit it replaced, None where nothing
    was capped."""
    now = address_space() if _ADDRESS_SPACE_OWNED else None
    if now is None:
        return None
    try:
        import resource

        old, hard = resource.getrlimit(resource.RLIMIT_AS)
        soft = now + int(extra)
        if hard != resource.RLIM_INFINITY:
            soft = min(soft, hard)
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
        return old
    except (ImportError, ValueError, OSError):
        return None


@contextlib.contextmanager
def small_allocations(extra: int = 64 << 20):
    """A block whose allocations together stay under `extra` bytes in a reader process: a C
    library that a damaged file makes allocate gigabytes for a small header value (a string of
    4 GiB) fails with MemoryError at once instead of filling memory until the time limit."""
    old = cap_address_space(extra)
    try:
        yield
    finally:
        if old is not None:
            import resource

            resource.setrlimit(resource.RLIMIT_AS, (old, resource.getrlimit(resource.RLIMIT_AS)[1]))


class InflationBudget:
    """How much one file's compressed data may inflate to, in all: max(INFLATE_FLOOR, the
    inflate-ratio limit x the file's size). Each compressed array spends its declared size
    before it is inflated."""

    def __init__(self, file_bytes: int, what: str):
        self.what = what
        self.file_bytes = int(file_bytes)
        self.allowed = max(INFLATE_FLOOR, current().max_inflate_ratio * self.file_bytes)
        self.spent = 0

    def spend(self, nbytes: int, part: str):
        self.spent += int(nbytes)
        if self.spent > self.allowed:
            raise ResourceLimitError(
                f"{part}: the compressed data of {self.what} ({format_size(self.file_bytes)}) would inflate to "
                f"{format_size(self.spent)} or more, over {current().max_inflate_ratio}x the file's size "
                f"(real data compress far less; raise HOVR_MAX_INFLATE_RATIO if this file is genuine)")


def inflate(data, max_bytes: int, what: str, codec: str = "zlib", exact: bool = False) -> tuple[bytes, bytes]:
    """(output, unused input) of one compressed stream, never producing more than max_bytes
    (checked against the memory limit first). data: bytes, or an iterable of byte chunks, taken
    only as long as the output stays within the bound (a stream refused early is never decoded
    whole). exact: the output must be exactly max_bytes. Raises ValueError naming `what` for a
    broken, truncated or oversized stream."""
    check_bytes(max_bytes, f"inflating {what}")
    if codec == "zlib":
        d = zlib.decompressobj()
        err = zlib.error
    elif codec == "lzma":
        d = lzma.LZMADecompressor()
        err = lzma.LZMAError
    else:
        raise ValueError(f"{what}: unknown compression {codec!r}")
    chunks = (data,) if isinstance(data, (bytes, bytearray, memoryview)) else data
    out, unused = [], []
    produced = 0
    for chunk in chunks:
        progress()
        if d.eof:
            unused.append(bytes(chunk))
            continue
        try:
            piece = d.decompress(chunk, max_bytes + 1 - produced)
        except (err, EOFError) as exc:
            raise ValueError(f"{what}: not a valid {codec} stream ({exc})") from None
        out.append(piece)
        produced += len(piece)
        if produced > max_bytes or getattr(d, "unconsumed_tail", b""):
            raise ResourceLimitError(f"{what}: inflates to more than the {max_bytes} bytes it declares or needs")
        if d.eof:
            unused.append(d.unused_data)
    if not d.eof:
        raise ValueError(f"{what}: {codec} stream is truncated")
    result = out[0] if len(out) == 1 else b"".join(out)
    if exact and len(result) != max_bytes:
        raise ValueError(f"{what}: inflates to {len(result)} bytes, its header says {max_bytes}")
    return result, b"".join(unused)
