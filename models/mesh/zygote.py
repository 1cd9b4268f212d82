"""The reader zygote: a small long-lived helper process that forks one short-lived child per read.

A fork costs in proportion to the forking process's page tables: 10-35 ms from a service, worker or
CLI process of 200-250 MB (numpy, scipy, VTK, torch loaded), more than VTK's whole read of a 10^4-cell
file. The zygote is a fresh interpreter that imports only numpy, meshio and our readers with VTK's
reader modules, once; its fork costs about a millisecond.

One zygote per reading process, started lazily in the background at its first sandboxed read (that
read, and any read while the zygote imports, forks the caller as before). Then, per read, through a
Unix socket (SOCK_SEQPACKET): the caller sends (fn, args, limits, environment, working folder) and
a memfd (socket.send_fds) straight to the spare child the zygote announced (its pid and request
socket, sent to the caller when it is forked), and tells the zygote, which watches it from then on
(one wake-up less than the zygote's hand: 0.76 ms against 1.3 ms for an empty read here); where no
spare is announced yet, or it died waiting, the zygote hands the request to its spare child (forked ahead of the request,
isolated and warmed up while it waits: _spare, models.mesh.warmup), which reads under this read's limits
(_child below: RLIMIT_AS, RLIMIT_CPU) and writes its answer into the memfd; the next spare is
forked after the answer (a spare found dead at a request: a child forked then takes the read). One
child serves one read and exits, as before the spare. The caller also hands a pipe of its own with
the memfd: the child's answer byte goes straight to the caller (one hop less). The zygote enforces
the deadline, reports the child's pid (the caller copies a lent answer's arrays from that
process: answer.dump's lend, where the zygote's first word, the address of a probe in its memory,
shows process_vm_readv allowed; the child waits on a pipe of the caller's until it has) and then
its end (answered, killed by signal N, timed out;
for a read answered straight to the caller, taken before its next request), so the caller words a
crash, a hang or a blow-up exactly as for a child of its own. If the zygote dies, the read in
flight is done by a direct fork, a new zygote is started, and a log line (logger "magnet.read")
says so; the user never sees it. The zygote exits when its caller closes the socket (exits).

MAGNET_READ_ZYGOTE=0: no zygote (every sandboxed read forks the caller).
"""

from __future__ import annotations

import logging
import os
import pickle
import select
import signal
import socket
import struct
import subprocess
import sys
import threading
import time

from models.errors import MagnetError, MeshError, ModelError, ParameterError
from models.mesh.answer import dump
from models.mesh.warmup import apply_environ, prewarm, warm_up

log = logging.getLogger("magnet.read")
log.addHandler(logging.NullHandler())  # a library's log line: never printed to a CLI user unasked

# what a read imports (the readers, the validation's modules and theirs), imported once in the
# zygote: a child importing them itself would pay it on every read
PRELOAD = (
    "numpy",
    "scipy.sparse",
    "scipy.sparse.csgraph",
    "scipy.sparse.linalg",
    "scipy.linalg",
    "meshio",
    "models.native",
    "models.mesh.read",
    "models.mesh.vtu",
    "models.mesh.xml_grid",
    "models.mesh.lattice",
    "models.mesh.ucd",
    "models.mesh.geometry",
    "models.mesh.orientation",
    "models.mesh.boundary",
    "models.mesh.dual",
    "models.mesh.vtk_readers",
    "models.mesh.sandbox",  # sandbox._read_in_child: the function every request names
    "vtkmodules.vtkCommonCore",
    "vtkmodules.vtkCommonDataModel",
    "vtkmodules.vtkIOXML",
    "vtkmodules.vtkIOLegacy",
    "vtkmodules.vtkIOExodus",
    "vtkmodules.vtkIOXdmf2",
    "vtkmodules.vtkIOCGNSReader",
    "vtkmodules.vtkIOHDF",
    "vtkmodules.vtkIOGeometry",
    "vtkmodules.util.numpy_support",
)
_ERRORS = {"MeshError": MeshError, "ParameterError": ParameterError, "ModelError": ModelError}
_MSG = 1 << 20  # the largest request (a pickled environment and a path: a few KB)
_SLACK_S = 10.0  # the zygote enforces the deadline; the caller waits this much longer for its word
_SETTLE_S = 5.0  # the most the next read waits for the zygote's word on a read answered straight to it
_PROBE = b"magnet zygote: may the caller borrow?"  # read by the caller from the zygote's memory


def _zygote_env() -> dict:
    """The zygote's environment: the caller's, with glibc's heap on transparent huge pages where
    the kernel offers them (glibc >= 2.35, ignored by older ones): a child's arrays live on its
    heap (warmup.prewarm), and the caller copies them from there (answer.dump's lend): 2 MiB pages
    copy several times faster than 4 KiB ones."""
    env = dict(os.environ)
    tunables = [
        t for t in env.get("GLIBC_TUNABLES", "").split(":") if t and not t.startswith("glibc.malloc.hugetlb=")
    ]
    env["GLIBC_TUNABLES"] = ":".join([*tunables, "glibc.malloc.hugetlb=1"])
    return env


class ZygoteLost(Exception):
    """The zygote did not answer (it died, or its socket broke): read by a direct fork instead."""


# ---------------------------------------------------------------- the caller's side


class Zygote:
    """The caller's handle: the zygote process and its socket."""

    def __init__(self) -> None:
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        code = "import sys; sys.path[:0] = sys.argv[2:]; from models.mesh.zygote import serve; serve(int(sys.argv[1]))"
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-c", code, str(theirs.fileno()), *[p for p in sys.path if p]],
                pass_fds=[theirs.fileno()],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                cwd=os.getcwd(),
                env=_zygote_env(),
            )
        except BaseException:
            ours.close()
            raise
        finally:
            theirs.close()
        self.sock = ours
        self.owner = os.getpid()
        self.env = dict(os.environ)  # the caller's, as the zygote got it (a request's None: this one)
        self.ready = False
        self.owed = False  # a read answered straight to us: the zygote's "done" for it still to come
        self.lend = False  # its children lend their answer's arrays (process_vm_readv works here)
        self.spare: tuple[int, socket.socket] | None = None  # the spare's pid and request socket
        self.used = 0  # the pid of the last child the zygote handed a request (its announcement is stale)
        self.lock = threading.Lock()

    def poll_ready(self) -> bool:
        """True once the zygote has imported its modules and said so (never blocks)."""
        if not self.ready:
            if not select.select([self.sock], [], [], 0)[0]:
                return False
            said = self.sock.recv(64)
            if said[:1] != b"R":
                raise ZygoteLost("the zygote ended while starting")
            if len(said) == 9 and os.environ.get("MAGNET_READ_LEND", "1") != "0":
                from models.mesh.answer import can_borrow

                self.lend = can_borrow(self.proc.pid, int.from_bytes(said[1:], "little"), _PROBE)
            self.ready = True
        return True

    def run(self, request: bytes, shm: int, timeout_s: float, release: int = -1):
        """Send one read; ('timeout'|signal|0, answered, the child's pid) as sandbox._wait gives
        for a direct child. The child's answer byte comes straight to us on a pipe of ours (one hop
        less); the zygote's word ("done": answered, killed by signal N, timed out) covers every
        other end, and for an answered read it is taken before the next request (`owed`).
        release: the read end of a pipe of ours, handed to the child: it lends its answer's arrays
        (answer.dump's lend) and waits until the pipe's other end closes (the caller has copied).
        The zygote's word on the last read is taken first (_direct's _direct_poll)."""
        r, w = os.pipe()
        pid = None
        done = False
        try:
            fds = [shm, w] + ([release] if release >= 0 else [])
            try:
                pid = self._direct(request, fds, timeout_s)
                if pid is None:
                    socket.send_fds(self.sock, [request], fds)
            except OSError as exc:
                raise ZygoteLost(f"cannot send to the zygote ({exc.strerror})") from None
            finally:
                os.close(w)
            limit = time.monotonic() + timeout_s + _SLACK_S
            watch = [self.sock, r]
            answered = False
            while True:
                if answered and pid is not None:
                    done = self.owed = True
                    return (0, True, pid)
                got = self._next(watch, limit, "the zygote did not answer within the deadline", r)
                if got is None:
                    continue
                if got == b"1":  # the answer is whole (its pid, the zygote's word, may follow)
                    answered = True
                    watch = [self.sock]
                    continue
                if isinstance(got, bytes):
                    watch = [self.sock]  # the child ended without answering: the zygote says how
                    continue
                kind, value = got
                if kind == "pid":
                    pid = self.used = value
                    if self.spare is not None and self.spare[0] == value:  # announced, then handed
                        self._drop_spare()
                elif kind == "done":
                    if value[0] == "stale":
                        raise ZygoteLost("a request went to a spare that had one already")
                    done = True
                    return (*value, pid)
        finally:
            os.close(r)
            if not done and pid is not None:  # interrupted or lost: no reader left running
                try:
                    os.kill(pid, signal.SIGKILL)
                except (ProcessLookupError, PermissionError):
                    pass

    def _direct(self, request: bytes, fds: list[int], timeout_s: float) -> int | None:
        """Hand the request straight to the spare the zygote announced (one hop less: the zygote
        is told after, to watch it), and return its pid; None where there is no spare announced
        yet, or it cannot take it (the zygote then hands the request: to the spare, or a child
        forked then)."""
        self._direct_poll()
        if self.spare is None:
            return None
        pid, conn = self.spare
        self.spare = None
        try:
            socket.send_fds(conn, [request], fds)
        except OSError:  # it died waiting: the zygote's way
            return None
        finally:
            conn.close()
        self.sock.send(b"S" + struct.pack("<qd", pid, timeout_s))
        return pid

    def _direct_poll(self) -> None:
        """Take an announcement that came since the last read (after the zygote's word on that
        read, when owed: _settle)."""
        self._settle()
        while select.select([self.sock], [], [], 0)[0]:
            if self._next([self.sock], time.monotonic() + _SETTLE_S, "the zygote did not answer") is not None:
                raise ZygoteLost("the zygote spoke out of turn")

    def _settle(self) -> None:
        """Take the zygote's word on the last read when it answered straight to us (the zygote
        hears the child's byte microseconds after us; a child stopped between its two bytes is
        ended by the zygote's deadline, too late for the next read: the zygote is replaced)."""
        if not self.owed:
            return
        limit = time.monotonic() + _SETTLE_S
        while True:
            got = self._next([self.sock], limit, "the zygote did not report the end of the last read")
            if got is not None and got[0] == "done":
                self.owed = False
                return

    def _next(self, watch: list, limit: float, late: str, pipe: int | None = None):
        """One event before `limit` (monotonic): the byte read from `pipe` when it is ready, else the
        zygote's next message (kind, value); None when interrupted or nothing came yet. ZygoteLost
        (`late`) past the limit, and when the socket breaks or the zygote ends."""
        left = limit - time.monotonic()
        if left <= 0:
            raise ZygoteLost(late)
        try:
            ready = select.select(watch, [], [], left)[0]
            if not ready:
                return None
            if pipe is not None and pipe in ready:
                return os.read(pipe, 1)
            msg, fds, _, _ = socket.recv_fds(self.sock, 4096, 1)
        except InterruptedError:
            return None
        except OSError as exc:
            raise ZygoteLost(f"the zygote's socket broke ({exc.strerror})") from None
        if not msg:
            raise ZygoteLost("the zygote ended")
        got = pickle.loads(msg)
        if got[0] == "spare":  # the next spare's pid and request socket: kept for the next read
            if fds:
                conn = socket.socket(fileno=fds[0])
                if got[1] == self.used:  # a spare the zygote handed a request already
                    conn.close()
                else:
                    self._drop_spare()
                    self.spare = (got[1], conn)
            return None
        for f in fds:
            os.close(f)
        return got

    def _drop_spare(self) -> None:
        if self.spare is not None:
            self.spare[1].close()
            self.spare = None

    def close(self) -> None:
        self._drop_spare()
        try:
            self.sock.close()
        finally:
            if self.proc.poll() is None:
                try:
                    self.proc.wait(2)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait()


_ZYGOTE: Zygote | None = None
_START = threading.Lock()


def enabled() -> bool:
    return os.environ.get("MAGNET_READ_ZYGOTE", "1") != "0"


def acquire(start: bool = True) -> Zygote | None:
    """This process's zygote, ready and locked for one read; None when there is none yet (started
    now in the background when `start`), it is busy with another thread's read, or it cannot run."""
    global _ZYGOTE
    if not enabled():
        return None
    with _START:
        z = _ZYGOTE
        if z is not None and z.owner != os.getpid():  # inherited through a fork: its socket is the parent's
            z = _ZYGOTE = None
        if z is not None and z.proc.poll() is not None:
            log.warning(
                "the reader zygote (pid %d) ended (exit status %s); starting a new one",
                z.proc.pid,
                z.proc.returncode,
            )
            _discard(z)
            z = _ZYGOTE = None
        if z is None:
            if start:
                try:
                    _ZYGOTE = Zygote()
                except OSError as exc:
                    log.warning("cannot start the reader zygote (%s); reading by direct forks", exc)
            return None
    if not z.lock.acquire(blocking=False):
        return None
    try:
        if z.poll_ready():
            return z
    except (ZygoteLost, OSError) as exc:
        lost(z, str(exc))
    z.lock.release()
    return None


def release(z: Zygote) -> None:
    z.lock.release()


def lost(z: Zygote, why: str) -> None:
    """The zygote failed a read: drop it (a new one starts at the next read) and say so in the log."""
    global _ZYGOTE
    log.warning("the reader zygote (pid %d) was lost: %s; starting a new one", z.proc.pid, why)
    with _START:
        if _ZYGOTE is z:
            _ZYGOTE = None
    _discard(z)


def _discard(z: Zygote) -> None:
    try:
        z._drop_spare()
        z.sock.close()
    except OSError:
        pass
    if z.proc.poll() is None:
        z.proc.kill()
    z.proc.wait()


def shutdown() -> None:
    """End this process's zygote (tests; it also ends by itself when this process exits)."""
    global _ZYGOTE
    with _START:
        z, _ZYGOTE = _ZYGOTE, None
    if z is not None and z.owner == os.getpid():
        z.close()


def wait_ready(timeout_s: float = 120.0) -> bool:
    """Start this process's zygote if needed and wait until it serves reads (benches, tests)."""
    limit = time.monotonic() + timeout_s
    while time.monotonic() < limit:
        z = acquire()
        if z is not None:
            release(z)
            return True
        time.sleep(0.05)
    return False


def pid() -> int | None:
    """The zygote's pid, if this process has one running."""
    z = _ZYGOTE
    return z.proc.pid if z is not None and z.owner == os.getpid() and z.proc.poll() is None else None


# ---------------------------------------------------------------- the reading child (forked by
# the zygote, or by the caller itself: models.mesh.sandbox)


def _isolate() -> None:
    """The reading child's setup that needs no request (a spare child does it before one comes)."""
    import faulthandler
    import gc
    import resource

    gc.disable()  # a collection would touch every object: copy-on-write faults for nothing
    faulthandler.disable()  # its dump would go to a copy of stderr kept apart (pytest, PYTHONFAULTHANDLER)
    devnull = os.open(os.devnull, os.O_RDWR)
    for fd in (0, 1, 2):  # a C++ reader's error text never reaches the user's terminal
        os.dup2(devnull, fd)
    os.close(devnull)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))


def _usage() -> tuple[int, float]:
    """(address space in bytes, CPU seconds) this process uses now."""
    import resource

    with open("/proc/self/statm") as f:
        used = int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return used, usage.ru_utime + usage.ru_stime


def _limit(memory_bytes: int, timeout_s: float, usage: tuple[int, float] | None = None) -> None:
    """This read's limits: its address space may grow by memory_bytes from here, and it may use
    timeout_s (+2) seconds of CPU from here (a spare child has used some waiting for its request).
    usage: _usage() as a spare read it just before its request came (it does not grow while the
    spare waits), saving the request those reads."""
    import resource

    used, cpu_used = usage if usage is not None else _usage()
    _, hard = resource.getrlimit(resource.RLIMIT_AS)
    soft = used + int(memory_bytes)
    if hard != resource.RLIM_INFINITY:
        soft = min(soft, hard)
    resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
    cpu = int(cpu_used + 0.999) + int(timeout_s) + 2
    _, cpu_hard = resource.getrlimit(resource.RLIMIT_CPU)
    if cpu_hard == resource.RLIM_INFINITY or cpu < cpu_hard:
        resource.setrlimit(resource.RLIMIT_CPU, (cpu, cpu_hard))


def _child(
    fn,
    args,
    shm: int,
    w: int,
    memory_bytes: int,
    timeout_s: float,
    isolated: bool = False,
    tell: int = -1,
    release: int = -1,
    usage: tuple[int, float] | None = None,
) -> None:
    """One read in this (forked) process under the limits, its answer into the memfd, one byte "1"
    on w when it is whole (first on `tell`, the caller's own pipe, when the zygote handed one: the
    caller goes on without the zygote's hop); never returns. isolated: _isolate has run already (a
    spare child). release: the answer's arrays are lent (the memfd holds the header, the caller
    copies them from this process's memory) and kept until this pipe ends (the caller is done)."""
    code = 1
    try:
        if not isolated:
            _isolate()
        _limit(memory_bytes, timeout_s, usage)
        try:
            answer = ("ok", fn(*args))
        except MagnetError as exc:
            answer = ("error", type(exc).__name__ if type(exc).__name__ in _ERRORS else "MeshError", str(exc))
        except MemoryError:
            answer = ("memory",)
        except BaseException:  # a reader's own exception: worded by the parent, never shown raw
            answer = ("error", "MeshError", "")
        try:
            lent = dump(answer, shm, lend=release >= 0)
        except Exception:  # noqa: BLE001  (a value the raw answer cannot hold: worded as unreadable)
            lent = dump(("error", "MeshError", ""), shm)
        if tell >= 0:
            try:
                os.write(tell, b"1")
            except OSError:  # the caller went away: the zygote still hears the answer
                pass
        if release >= 0:
            _idle()  # woken when released, it runs only on an idle core: the caller's goes on
            try:  # until the caller has copied the lent arrays (or went away: the pipe ends too)
                os.read(release, 1)
            except OSError:
                pass
        del lent
        os.write(w, b"1")
        code = 0
        if release < 0:  # (a lending child is idle since its answer)
            _idle()  # its exit (unmapping its memory) yields the CPU to the caller taking the answer
    except BaseException:
        pass
    finally:
        os._exit(code)


def _idle() -> None:
    """This process scheduled only where a core would idle (SCHED_IDLE; nice 19 where that is not
    allowed): the answered child's last steps never preempt the caller."""
    try:
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except (AttributeError, OSError):
        try:
            os.setpriority(os.PRIO_PROCESS, 0, 19)
        except OSError:
            pass


# ---------------------------------------------------------------- the zygote's side


def serve(fd: int) -> None:
    """The zygote's loop (in its own interpreter): preload, fork the first spare child, say ready;
    per request, hand it to the spare (or, the spare being dead, to a child forked now), watch that
    child to its end, answer, then fork the next spare."""
    import gc
    import importlib

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the caller's to handle
    sock = socket.socket(fileno=fd)
    for name in PRELOAD:
        try:
            importlib.import_module(name)
        except Exception:  # noqa: BLE001  (a module missing here is imported by the child that needs it)
            pass
    import shutil
    import tempfile

    folder = tempfile.mkdtemp(prefix="magnet-zygote-")
    paths = warm_up(folder)
    gc.collect()
    gc.freeze()  # the children never copy these objects' pages for a collection
    pending: list[int] = []
    spare = _fork_spare(sock, paths)
    import ctypes

    probe = ctypes.create_string_buffer(_PROBE, len(_PROBE))  # the caller reads it: can it borrow?
    sock.send(b"R" + ctypes.addressof(probe).to_bytes(8, "little"))
    _announce(sock, spare)
    while True:
        try:
            msg, fds, _, _ = socket.recv_fds(sock, _MSG, 3)
        except OSError:
            break
        if not msg:  # the caller exited
            break
        for f in fds[3:]:
            os.close(f)
        if not fds and msg[:1] == b"S" and len(msg) == 17:
            if spare is None:
                sock.send(pickle.dumps(("done", ("stale", False))))
                continue
            # the caller handed the request to the spare itself: watch it from here
            pid, timeout_s = struct.unpack_from("<qd", msg, 1)
            if pid != spare[0]:  # (cannot happen: the caller drops an announcement once handed)
                sock.send(pickle.dumps(("done", ("stale", False))))
                continue
            child, r = spare[0], spare[2]
            spare[1].close()
            spare = None
            told = True
        elif not fds:
            continue
        else:
            timeout_s = struct.unpack_from("<d", msg)[0]  # (the request itself is the child's to unpickle)
            try:
                child, r = _hand(spare, msg, fds[:3], sock, paths)
            finally:
                spare = None
                for f in fds[:3]:
                    os.close(f)
            told = False
        try:
            if not told:
                sock.send(pickle.dumps(("pid", child)))
            status = _watch(child, r, sock, timeout_s, pending)
        finally:
            os.close(r)
        if status is None:  # the caller went away mid-read
            break
        sock.send(pickle.dumps(("done", status)))
        spare = _fork_spare(sock, paths)  # after the answer: its fork is off the next read's path
        _announce(sock, spare)
    if spare is not None:
        spare[1].close()  # the spare's request channel ends: it exits
    sock.close()
    shutil.rmtree(folder, ignore_errors=True)


def _announce(sock: socket.socket, spare) -> None:
    """Tell the caller the spare's pid and give it the spare's request socket: its next request
    goes straight to the spare (Zygote._direct)."""
    try:
        socket.send_fds(sock, [pickle.dumps(("spare", spare[0]))], [spare[1].fileno()])
    except OSError:
        pass


def _fork_spare(sock: socket.socket, paths: list[str], warm: bool = True):
    """A child forked ahead of the request (isolated, waiting on its own socket for one request):
    (pid, the socket to hand it the request, the read end of its answer pipe)."""
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    r, w = os.pipe()
    child = os.fork()
    if child == 0:  # never returns
        sock.close()
        ours.close()
        os.close(r)
        _spare(theirs, w, paths if warm else [], warm)
    theirs.close()
    os.close(w)
    return child, ours, r


def _spare(conn: socket.socket, w: int, paths: list[str], warm: bool) -> None:
    """The spare child: isolated now, then one request (its read, its answer), then its end.
    The zygote gone (its socket ended) or a malformed request: it exits without a read."""
    try:
        _isolate()
        if warm:
            prewarm(conn, paths)
        usage = _usage()
        msg, fds, _, _ = socket.recv_fds(conn, _MSG, 3)
        conn.close()
        for f in fds[3:]:
            os.close(f)
        if not msg or not fds:
            os._exit(0)
        fn, args, memory_bytes, timeout_s, env, cwd = pickle.loads(msg[8:])
        if env is not None:  # None: the caller's environment is the one the zygote started with
            apply_environ(env)
        try:
            os.chdir(cwd)
        except OSError:
            pass
    except BaseException:
        os._exit(1)
    _child(
        fn,
        args,
        fds[0],
        w,
        memory_bytes,
        timeout_s,
        isolated=True,
        tell=fds[1] if len(fds) > 1 else -1,
        release=fds[2] if len(fds) > 2 else -1,
        usage=usage,
    )


def _hand(spare, msg: bytes, fds: list[int], sock: socket.socket, paths: list[str]):
    """Give the request to the spare child; a spare that died waiting (its answer pipe at its end)
    or that cannot take it is collected, and a child forked now takes it. (pid, answer pipe)."""
    if spare is not None:
        child, conn, r = spare
        try:
            if not select.select([r], [], [], 0)[0]:  # no end of file: the spare is alive
                socket.send_fds(conn, [msg], fds)
                return child, r
        except OSError:
            pass
        finally:
            conn.close()
        os.close(r)
        _end(child)
    child, conn, r = _fork_spare(sock, paths, warm=False)  # the request waits: no warm-up
    try:
        socket.send_fds(conn, [msg], fds)
    finally:
        conn.close()
    return child, r


def _end(child: int) -> None:
    try:
        os.kill(child, signal.SIGKILL)
    except ProcessLookupError:
        pass
    try:
        os.waitpid(child, 0)
    except ChildProcessError:
        pass


def _watch(child: int, r: int, sock: socket.socket, timeout_s: float, pending: list[int]):
    """Wait for the child's answer byte, its end or the deadline; (status, answered) as
    sandbox._wait, or None when the caller's socket closed (the child is then killed)."""
    limit = time.monotonic() + timeout_s
    while True:
        left = limit - time.monotonic()
        if left <= 0:
            os.kill(child, signal.SIGKILL)
            os.waitpid(child, 0)
            return ("timeout", False)
        try:
            ready = select.select([r, sock], [], [], left)[0]
        except InterruptedError:
            continue
        if r in ready:
            break
        if sock in ready:  # the caller never writes during a read: it closed, or died
            os.kill(child, signal.SIGKILL)
            os.waitpid(child, 0)
            return None
    answered = os.read(r, 1) == b"1"
    if answered:  # the child exits on its own; collected at a later request
        pending.append(child)
        for p in list(pending):
            try:
                if os.waitpid(p, os.WNOHANG)[0]:
                    pending.remove(p)
            except ChildProcessError:
                pending.remove(p)
        return (0, True)
    _, code = os.waitpid(child, 0)
    return ((os.WTERMSIG(code) if os.WIFSIGNALED(code) else 0), False)
