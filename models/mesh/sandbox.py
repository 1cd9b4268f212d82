"""Reading untrusted mesh files safely: in a forked child with a time and a memory limit.

Readers written in C++ (VTK's) can crash on a corrupted file, and any reader can loop or blow up
its memory on a file that lies about its sizes. `read_mesh_safe` runs `models.mesh.read.read_mesh`
in a child forked from this process (a fork costs milliseconds: the child already has every module
the parent imported) under RLIMIT_AS (the parent's address space plus `memory_bytes`) and a
deadline. A segfault, an abort, a hang or a memory blow-up becomes one MeshError sentence naming
the file and the format ("the Exodus II reader crashed on this file: it is corrupted or not
Exodus II"); the calling process lives on.

The child reads; the parent builds (models.mesh.deferred): in the child the builders hand back
their arguments, the reader's arrays, and the parent checks them and makes the Mesh with our own
code (`_built`). The answer is never a pickle (models.mesh.answer): a JSON header in a memfd the
parent seals (nobody can write it any more), and the arrays, copied by the parent out of the
child's memory (process_vm_readv, where the zygote's probe allows it: the child waits until the
parent has built the Mesh) or else raw in the memfd, mapped private. A child taken over by a reader
exploit can write any bytes: nothing it writes is run, and anything inconsistent is worded as a
crashed reader. The child runs with the garbage collector off (no copy-on-write faults from a
collection), and once it is released the parent goes on while it exits (collected at the next read
or at exit).

Every message also gets the same wording here, in-process or not (`wording`): it names the file
and the format, and a library's raw exception text or a Python repr is replaced by a sentence.
The CLI, the HTTP API and the worker all read through this function, so they word a failure alike.

The child is forked by the reader zygote (models.mesh.zygote: a helper interpreter holding only the
readers' modules, started in the background at the first sandboxed read) once it is ready, else by
this process. The zygote's child is a spare forked and warmed up ahead of the request (one read per
child still; the fork off the read's path). In-process reads run under the same deadline (SIGALRM, `deadline`).

The CLI reads through `read_mesh_cli`: in-process when the reader is pure Python (it cannot crash
the interpreter), in a child forked by the CLI itself when it is native (VTK, HDF5, netCDF).

MAGNET_READ_SANDBOX=0 reads in-process (no fork); MAGNET_READ_ZYGOTE=0 forks without a zygote;
MAGNET_READ_TIMEOUT_S and MAGNET_READ_MEMORY_MB
change the default limits (600 s; the machine's physical memory).
"""

from __future__ import annotations

import atexit
import contextlib
import os
import pickle
import re
import select
import signal
import struct
import threading
import time

from models.errors import MagnetError, MeshError, ParameterError
from models.mesh import answer, heap
from models.mesh.formats import ARCHIVES, extension, format_name, not_found
from models.mesh.zygote import _ERRORS, _child

DEFAULT_TIMEOUT_S = 600.0

# A library's own text or a Python repr in a message: never shown to a user as it is.
RAW_TEXT = re.compile(
    "|".join(
        [
            r"\bnp\.\w+\(",  # np.int64(6)
            r"\b(?:array|dtype)\(",
            r"<[\w.]+ object at 0x",
            r"\bSystemExit\b",
            r"Traceback \(most recent call last\)",
            r"\b\w*(?:Error|Exception)\b(?! in the mesh)",  # KeyError, ValueError, ParseError, ...
            r"out of bounds for (?:axis|size)",
            r"index out of range",
            r"invalid literal for",
            r"could not convert",
            r"cannot reshape",
            r"codec can't (?:de|en)code",
            r"No module named",
            r"Could not find \.//",
            r"values to unpack",
            r"unpack requires",
            r"buffer (?:is )?(?:smaller|size)",
            r"has no attribute",
            r"object is not",
            r"unsupported operand",
            r"Implementation assumes",
            r"not well-formed|mismatched tag|junk after document|unclosed token|no element found",
            r"undefined entity|syntax error",
            r"\bvtk[A-Z]\w+",  # vtkXMLUnstructuredGridReader (C++ class names)
            r"\.(?:cxx|cpp|pyx|py):\d+",
            r"^\s*'[^']*'\s*$",  # a bare quoted key: KeyError('vtkidtype') as str
            r":\s*'[^']*'\s*$",
            r"\[Errno \d+\]",
        ]
    )
)


def is_raw(message: str) -> bool:
    """True when `message` carries a library's raw exception text or a Python repr."""
    return bool(RAW_TEXT.search(message or ""))


def wording(message: str, path: str | os.PathLike, file_format: str | None = None) -> str:
    """The message of a failed read as users get it everywhere: naming the file and the format,
    with no raw library text (replaced by what is known: the format, and a line when one is given)."""
    name = os.path.basename(os.fspath(path))
    fmt = format_name(path, file_format)
    message = " ".join((message or "").split())
    if not message or is_raw(message):
        line = re.search(r"\bline (\d+)", message or "")
        where = f" (near line {line.group(1)})" if line else ""
        return f"cannot read {name} as {fmt}: the file is corrupted or not {fmt}{where}"
    if (name in message and fmt in message) or (
        message.startswith(f"cannot read {name} as ")
        and not message.startswith(f"cannot read {name} as a mesh: ")
    ):  # (the file and a format said already)
        return message
    for prefix in (f"cannot read {name} as a mesh: ", f"cannot read {name}: ", f"{name}: "):
        if message.startswith(prefix):
            message = message[len(prefix) :]
    if fmt == "mesh":  # (no format known by its extension: the message says what is wrong)
        return f"cannot read {name}: {message}"
    return f"cannot read {name} as {fmt}: {message}"


def crash_sentence(path, file_format: str | None = None) -> str:
    name, fmt = os.path.basename(os.fspath(path)), format_name(path, file_format)
    return f"cannot read {name} as {fmt}: the {fmt} reader crashed on this file: it is corrupted or not {fmt}"


def timeout_sentence(path, timeout_s: float, file_format: str | None = None) -> str:
    name, fmt = os.path.basename(os.fspath(path)), format_name(path, file_format)
    return (
        f"cannot read {name} as {fmt}: the {fmt} reader did not finish within {timeout_s:g} s: "
        f"the file is corrupted, not {fmt}, or too large for this limit"
    )


def memory_sentence(path, memory_bytes: int, file_format: str | None = None) -> str:
    name, fmt = os.path.basename(os.fspath(path)), format_name(path, file_format)
    return (
        f"cannot read {name} as {fmt}: the {fmt} reader needed more than {memory_bytes / 2**30:.1f} GiB "
        f"of memory: the file is corrupted, not {fmt}, or too large for this limit"
    )


def _default_timeout() -> float:
    raw = os.environ.get("MAGNET_READ_TIMEOUT_S")
    if raw is None:
        return DEFAULT_TIMEOUT_S
    try:
        value = float(raw)
    except ValueError:
        value = float("nan")
    if not value > 0 or value == float("inf"):
        from models.mesh.read import env_ignored

        env_ignored("MAGNET_READ_TIMEOUT_S", raw, f"a number of seconds > 0; {DEFAULT_TIMEOUT_S:g} s it is")
        return DEFAULT_TIMEOUT_S
    return value


def sandbox_enabled() -> bool:
    return (
        hasattr(os, "fork") and hasattr(os, "memfd_create") and os.environ.get("MAGNET_READ_SANDBOX") != "0"
    )


def read_mesh_safe(
    path: str | os.PathLike,
    physical_tag: str | None = None,
    file_format: str | None = None,
    weld: float | None = None,
    *,
    timeout_s: float | None = None,
    memory_bytes: int | None = None,
    in_process: bool = False,
    native: bool = True,
    zygote: bool = True,
):
    """`models.mesh.read.read_mesh` in a forked child under limits (see the module docstring);
    the same Mesh, or a MeshError / ParameterError worded for users. in_process: read here (the
    same wording; read_mesh_cli sets it for pure-Python readers); with native=False too, a file
    that needs a native reader raises read.NativeReaderNeeded instead of being read here."""
    from models.mesh import read

    path = os.fspath(path)
    if not os.path.exists(path):
        raise MeshError(not_found(path))
    if os.path.isdir(path):
        from models.mesh import case_files

        case = case_files.openfoam_file(path)
        if case is None:
            raise MeshError(
                f"{path} is a folder, not a mesh file (a folder is read only as an OpenFOAM case: "
                "constant/polyMesh and system/controlDict)"
            )
        path = case
    read.special_file(path)
    if file_format is None and extension(path) in ARCHIVES:  # XDMF + .h5 and the like, in one upload
        if os.path.getsize(path) == 0:  # (said as a mesh file's)
            raise MeshError(wording(f"{os.path.basename(path)}: the file is empty (0 bytes)", path))
        import shutil
        import tempfile

        from models.mesh.archive import unpack

        folder = tempfile.mkdtemp(prefix="magnet-archive-")
        try:
            inner = unpack(path, folder)
            return read_mesh_safe(
                inner, physical_tag, None, weld, timeout_s=timeout_s, memory_bytes=memory_bytes, zygote=zygote
            )
        finally:
            shutil.rmtree(folder, ignore_errors=True)
    kwargs = {"physical_tag": physical_tag, "file_format": file_format, "weld": weld}
    timeout_s = _default_timeout() if timeout_s is None else timeout_s
    try:
        if in_process or not sandbox_enabled():
            heap.keep()  # (as below: a second read in this process reuses the first one's pages)
            with deadline(timeout_s):
                return read.read_mesh(path, **kwargs, **({} if native else {"native": False}))
        memory_bytes = read.default_memory() if memory_bytes is None else memory_bytes
        heap.keep()  # this process's heap kept between reads: no page faults on the copied arrays
        held: list[int] = []
        try:
            got = call_in_child(
                _read_in_child,
                (path, kwargs),
                path=path,
                file_format=file_format,
                timeout_s=timeout_s,
                memory_bytes=memory_bytes,
                zygote=zygote,
                hold=held,
            )
            return _built(got, path, file_format, memory_bytes)
        finally:  # the child ends now, and the zygote forks its next spare: not during the build
            for fd in held:
                os.close(fd)
    except read.NativeReaderNeeded:
        raise
    except MeshError as exc:
        raise MeshError(wording(str(exc), path, file_format)) from None
    except ParameterError:
        raise
    except MagnetError as exc:
        raise MeshError(wording(str(exc), path, file_format)) from None
    except ReadTimeout:  # in-process reading ran past the deadline
        raise MeshError(timeout_sentence(path, timeout_s, file_format)) from None
    except (Exception, SystemExit):  # a reader's own exception escaped (in-process reading)
        raise MeshError(wording("", path, file_format)) from None


class ReadTimeout(BaseException):
    """Raised by `deadline`'s alarm: a BaseException, so no reader's `except Exception` swallows it."""


@contextlib.contextmanager
def deadline(timeout_s: float | None):
    """An in-process read that runs past timeout_s raises ReadTimeout (SIGALRM through
    signal.setitimer, between two Python bytecodes: a loop in Python ends, a call into C ends when
    it returns). Only in the main thread. A real-time timer the caller set (pytest-timeout's, say)
    is kept: when it is due first it stays as it is; else it is put back afterwards with the time
    it has left."""
    if (
        not timeout_s
        or timeout_s <= 0
        or not hasattr(signal, "setitimer")
        or threading.current_thread() is not threading.main_thread()
    ):
        yield
        return
    theirs, interval = signal.getitimer(signal.ITIMER_REAL)
    if 0 < theirs <= timeout_s:  # the caller's alarm comes first: leave it alone
        yield
        return

    def alarm(signum, frame):
        raise ReadTimeout

    try:
        old = signal.signal(signal.SIGALRM, alarm)
    except (ValueError, OSError):  # not the main interpreter's main thread after all
        yield
        return
    start = time.monotonic()
    try:
        signal.setitimer(signal.ITIMER_REAL, float(timeout_s))
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
        if theirs > 0:
            signal.setitimer(signal.ITIMER_REAL, max(theirs - (time.monotonic() - start), 1e-3), interval)


# meshio readers that call into compiled libraries (HDF5, netCDF): read in the sandbox, like VTK's
NATIVE_MESHIO = frozenset({"med", "h5m", "xdmf", "exodus", "hmf", "cgns"})


def pure_python_reader(path: str, file_format: str | None = None) -> bool:
    """True when the reader read_mesh picks for `path` is Python and numpy only (our AVS UCD reader,
    meshio's text readers: gmsh, Abaqus, Nastran, medit, ...): it cannot crash the interpreter.
    VTK's readers, our VTU path (it falls back to VTK's reader) and meshio's HDF5/netCDF readers
    are native. An unreadable head answers False (the sandbox then words the failure)."""
    from models.mesh import read

    try:
        family, detail = read.pick_reader(path, file_format)
    except (MagnetError, OSError):
        return False
    return family == "ucd" or (family == "meshio" and detail not in NATIVE_MESHIO)


def read_mesh_cli(path, physical_tag=None, file_format=None, weld=None, **limits):
    """read_mesh_safe as the CLI reads: in-process when the reader is pure Python (no fork, no
    transfer), in the sandbox when it is native (VTK, HDF5, netCDF). A VTU, .vts, .vtr or .vti is
    read in-process when our numpy path reads it (models.mesh.vtu.read_vtu_simple,
    models.mesh.xml_grid.read_xml_grid: numpy and zlib only), in the sandbox (VTK's reader)
    otherwise. The service and the worker always read in the sandbox (read_mesh_safe)."""
    from models.mesh import read

    p = os.fspath(path)
    if sandbox_enabled() and os.path.isfile(p) and extension(p) not in ARCHIVES:
        if pure_python_reader(p, file_format):
            try:  # (a gmsh file that meshio refuses may need gmsh's library: the sandbox then)
                return read_mesh_safe(
                    path, physical_tag, file_format, weld, **limits, in_process=True, native=False
                )
            except read.NativeReaderNeeded:
                pass
        elif _numpy_family(p, file_format):
            try:
                return read_mesh_safe(
                    path, physical_tag, file_format, weld, **limits, in_process=True, native=False
                )
            except read.NativeReaderNeeded:
                pass  # a layout our numpy paths do not read: VTK's reader, in the sandbox
    # one read per CLI process: a direct fork (10-18 ms, bench/bench_fork_cost.py) costs less than
    # starting a zygote interpreter (about a second of CPU) that would serve no second read
    limits.setdefault("zygote", False)
    return read_mesh_safe(path, physical_tag, file_format, weld, **limits)


def _numpy_family(path: str, file_format: str | None) -> bool:
    """The file goes to one of our numpy readers first (read._read): a VTU, or a .vts, .vtr, .vti."""
    from models.mesh import read

    try:
        family, detail = read.pick_reader(path, file_format)
    except (MagnetError, OSError):
        return False
    return family == "vtu" or (family == "vtk" and detail in read.XML_GRIDS)


def _read_in_child(path, kwargs):
    """read_mesh in the reading child, its builders deferred: the reader's arrays come back as a
    models.mesh.deferred.Deferred, and the caller builds the Mesh (_built)."""
    from models.mesh import deferred, read  # looked up at call time: whatever read_mesh dispatches to

    deferred.DEFER = True  # (this process serves this one read)
    return read.read_mesh(path, **kwargs)


def _built(got, path: str, file_format: str | None, memory_bytes: int):
    """The Mesh of a read the child answered: built here from its arguments when it is a Deferred
    (checked first: an inconsistent one is worded as a crashed reader); refused as read_mesh
    refuses, so the words are the in-process read's."""
    from models.mesh import build, deferred, read

    if not isinstance(got, deferred.Deferred):
        return got
    try:
        return build.build_deferred(got, memory_bytes)
    except deferred.Inconsistent:
        raise MeshError(crash_sentence(path, file_format)) from None
    except MemoryError:
        raise MeshError(memory_sentence(path, memory_bytes, file_format)) from None
    except MeshError as exc:
        raise MeshError(read.refusal(str(exc), path, file_format)) from None


def _hdf5_damage(path: str):
    from models.mesh.containers import hdf5_damage

    return hdf5_damage(path)


def _damage_place(sentence: str, path: str, memory_bytes: int) -> str:
    """A crashed reader's sentence, for an HDF5 file (CGNS, Exodus II, Fluent .cas.h5, ...), with
    the object whose metadata is damaged in place of "it is corrupted or not ...": found by h5py in
    another child (containers.hdf5_damage). The sentence as it is where that child finds nothing,
    crashes too, or the file is no HDF5."""
    from models.mesh.containers import is_hdf5
    from models.mesh.read import _VAGUE

    if not is_hdf5(path):
        return sentence
    try:
        where = call_in_child(
            _hdf5_damage, (path,), path=path, timeout_s=10.0, memory_bytes=memory_bytes, zygote=False
        )
    except (MagnetError, OSError):
        return sentence
    vague = _VAGUE.search(sentence)
    if not isinstance(where, str) or not where or is_raw(where) or not vague:
        return sentence
    return sentence[: vague.start()] + where


def call_in_child(
    fn,
    args=(),
    *,
    path,
    file_format=None,
    timeout_s: float,
    memory_bytes: int,
    zygote: bool = True,
    hold: list | None = None,
):
    """fn(*args) in a forked child under the limits; its result (models.mesh.answer: arrays copied
    from the child or through a memfd, never a pickle), or the MagnetError it raised; a crash, hang or memory blow-up as a MeshError.
    The child is forked by this process's reader zygote (models.mesh.zygote) when it is running
    and `zygote`, else by this process. hold: a child that lent its arrays waits until the pipe
    put in this list is closed (by the caller, when it is done: the child's exit and the zygote's
    next fork then do not compete with the caller's work on the result); closed here without it."""
    shm = release = -1
    pid = None
    try:
        found = _via_zygote(fn, args, timeout_s, memory_bytes) if zygote else None
        if found is None:
            shm = os.memfd_create("magnet-read", os.MFD_CLOEXEC | os.MFD_ALLOW_SEALING)
            status, answered = _direct(fn, args, shm, timeout_s, memory_bytes)
        else:
            shm, status, answered, pid, release = found
        from models.mesh.read import _with_place  # (a crash's or hang's place, for the text formats

        # whose layout locate follows, and for HDF5 containers)
        if status == "timeout" or (not answered and status == signal.SIGXCPU):
            raise MeshError(_with_place(timeout_sentence(path, timeout_s, file_format), path, file_format))
        if not answered:
            crash = crash_sentence(path, file_format)
            said = _with_place(crash, path, file_format)
            if said != crash:  # the place found says what is wrong: no "crashed" before it
                said = said.replace(
                    f"the {format_name(path, file_format)} reader crashed on this file: ", "", 1
                )
            raise MeshError(said if fn is _hdf5_damage else _damage_place(said, path, memory_bytes))
        # a lent answer: its arrays copied from the child (alive until `release` closes), at most
        # what the child could hold
        got = _load(shm, pid if release >= 0 else None, memory_bytes)
        if got[0] == "ok":
            return got[1]
        if got[0] == "memory":
            raise MeshError(memory_sentence(path, memory_bytes, file_format))
        if got[0] == "corrupt":
            raise MeshError(crash_sentence(path, file_format))
        raise _ERRORS[got[1]](got[2])
    finally:
        if shm >= 0:
            os.close(shm)
        if release >= 0:
            if hold is not None:
                hold.append(release)
            else:
                os.close(release)  # the child may end now


def _direct(fn, args, shm: int, timeout_s: float, memory_bytes: int):
    """A child forked from this process: (status, answered) as _wait gives."""
    r, w = os.pipe()
    try:
        pid = os.fork()
        if pid == 0:  # the child: never returns
            os.close(r)
            _child(fn, args, shm, w, memory_bytes, timeout_s)
        os.close(w)
        w = -1
        return _wait(pid, r, timeout_s)
    finally:
        os.close(r)
        if w >= 0:
            os.close(w)


def _importable(fn) -> bool:
    """fn can be named in another interpreter: a module's top-level function, not __main__'s."""
    module = getattr(fn, "__module__", None)
    name = getattr(fn, "__qualname__", "")
    if not module or module == "__main__" or "<" in name or "." in name:
        return False
    import sys

    return getattr(sys.modules.get(module), name, None) is fn


def _via_zygote(fn, args, timeout_s: float, memory_bytes: int):
    """(memfd, status, answered, the child's pid, release) from a child of the zygote, or None
    where it cannot serve this read (none running yet, busy with another thread's read, fn not
    importable, zygote lost). release: where the zygote's children lend their answer's arrays
    (Zygote.lend), the write end of the pipe the child waits on until they are copied (-1 else)."""
    from models.mesh import zygote

    if not _importable(fn):
        return None
    z = zygote.acquire()
    if z is None:
        return None
    try:
        try:
            env = dict(os.environ)
            request = struct.pack("<d", timeout_s) + pickle.dumps(
                (fn, args, memory_bytes, timeout_s, None if env == z.env else env, os.getcwd())
            )  # the deadline first, for the zygote: it never unpickles; the environment only
            # where it changed since the zygote started (its spares have that one already)
        except Exception:  # noqa: BLE001  (arguments that do not pickle: a direct fork takes them)
            return None
        shm = os.memfd_create("magnet-read", os.MFD_CLOEXEC | os.MFD_ALLOW_SEALING)
        wait, release = os.pipe() if z.lend else (-1, -1)
        try:
            status, answered, pid = z.run(request, shm, timeout_s, wait)
        except zygote.ZygoteLost as exc:
            os.close(shm)
            _close(release)
            zygote.lost(z, str(exc))
            return None
        except BaseException:
            os.close(shm)
            _close(release)
            zygote.lost(z, "a read was interrupted")
            raise
        finally:
            _close(wait)
        return shm, status, answered, pid, release
    finally:
        zygote.release(z)


def _close(fd: int) -> None:
    if fd >= 0:
        os.close(fd)


def _wait(pid: int, r: int, timeout_s: float):
    """Wait for the child's one-byte answer (or the pipe's end: it died); ('timeout'|signal|0, answered)."""
    deadline = time.monotonic() + timeout_s
    done = False
    try:
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return "timeout", False
            try:
                ready, _, _ = select.select([r], [], [], left)
            except InterruptedError:
                continue
            if ready:
                break
        answered = os.read(r, 1) == b"1"
        done = True
        if answered:  # the answer is whole: the child's exit (unmapping its memory) runs on meanwhile
            _reap_later(pid)
            return 0, True
        _, code = os.waitpid(pid, 0)
        return (os.WTERMSIG(code) if os.WIFSIGNALED(code) else 0), answered
    finally:
        if not done:  # timeout, or the caller interrupted (Ctrl-C, a job cancelled): no child left behind
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            os.waitpid(pid, 0)


_PENDING: list[int] = []  # children that answered and are still exiting


def _reap_later(pid: int) -> None:
    """Collect `pid` without waiting for it: a child that answered spends milliseconds unmapping
    its copy of this process's memory; that runs while the caller goes on. Children collected at
    the next read (and at exit), never left as zombies for long."""
    _PENDING.append(pid)
    for p in list(_PENDING):
        try:
            done, _ = os.waitpid(p, os.WNOHANG)
        except ChildProcessError:
            done = p
        if done:
            _PENDING.remove(p)


def _reap_all() -> None:
    for p in list(_PENDING):
        try:
            os.waitpid(p, 0)
        except ChildProcessError:
            pass
    _PENDING.clear()


atexit.register(_reap_all)


def _load(shm: int, pid: int | None = None, limit: int | None = None):
    """The child's answer (models.mesh.answer: a JSON header and raw arrays, every byte checked;
    lent arrays copied from the child `pid`); a malformed one is worded as a crashed reader."""
    try:
        return answer.load(shm, pid, limit)
    except answer.Corrupt:
        return ("corrupt",)


__all__ = [
    "read_mesh_safe",
    "read_mesh_cli",
    "pure_python_reader",
    "call_in_child",
    "wording",
    "is_raw",
    "sandbox_enabled",
    "crash_sentence",
    "timeout_sentence",
    "memory_sentence",
]
