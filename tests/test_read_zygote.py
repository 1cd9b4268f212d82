"""The reader zygote (models.mesh.zygote): the reading child forked by a small helper process, its
end (crash, deadline, memory) worded exactly as for a child of the caller; a dead zygote replaced,
with a log line."""

from __future__ import annotations

import ctypes
import logging
import os
import signal
import time

import pytest

from models.errors import MeshError
from models.mesh import zygote
from models.mesh.sandbox import call_in_child, crash_sentence, memory_sentence, timeout_sentence

PATH = "broken.exo"


@pytest.fixture
def ready(monkeypatch):
    monkeypatch.setenv("MAGNET_READ_ZYGOTE", "1")
    assert zygote.wait_ready(120), "the zygote did not start"
    yield zygote.pid()
    zygote.shutdown()


def _call(fn, *args, **kw):
    return call_in_child(fn, args, path=PATH, timeout_s=kw.pop("timeout_s", 30), memory_bytes=1 << 30, **kw)


def test_the_child_is_the_zygotes_and_direct_forks_remain(ready):
    assert _call(os.getppid) == ready  # forked by the zygote
    assert _call(os.getppid, zygote=False) == os.getpid()  # by this process
    assert _call(os.getppid, zygote=True) == ready


def test_crash_deadline_and_memory_are_worded_as_for_a_direct_child(ready):
    for z in (True, False):
        with pytest.raises(MeshError) as err:
            _call(ctypes.string_at, 0, zygote=z)  # a segfault in the child
        assert str(err.value) == crash_sentence(PATH)
        with pytest.raises(MeshError) as err:
            _call(time.sleep, 60, timeout_s=1, zygote=z)
        assert str(err.value) == timeout_sentence(PATH, 1)
        with pytest.raises(MeshError) as err:
            _call(bytearray, 8 << 30, zygote=z)
        assert str(err.value) == memory_sentence(PATH, 1 << 30)
    assert zygote.pid() == ready  # the zygote lived through all of it


def test_a_dead_zygote_is_replaced_and_logged(ready, caplog):
    os.kill(ready, signal.SIGKILL)
    time.sleep(0.2)
    with caplog.at_level(logging.WARNING, logger="magnet.read"):
        assert _call(os.getppid) == os.getpid()  # this read: a direct fork
    assert any("reader zygote" in r.getMessage() and "new one" in r.getMessage() for r in caplog.records)
    assert zygote.wait_ready(120)
    assert zygote.pid() not in (None, ready)
    assert _call(os.getppid) == zygote.pid()


# ---------------------------------------------------------------- the spare child


def _alive_children(pid: int) -> list[int]:
    """The zygote's children that are not zombies (an answered child may linger until collected)."""
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            kids = [int(k) for k in f.read().split()]
    except FileNotFoundError:
        pytest.skip("no /proc/PID/task/PID/children on this kernel")
    alive = []
    for k in kids:
        try:
            with open(f"/proc/{k}/stat") as f:
                if f.read().rsplit(")", 1)[1].split()[0] != "Z":
                    alive.append(k)
        except (FileNotFoundError, ProcessLookupError):  # ended and collected meanwhile
            pass
    return alive


def _spare(zygote_pid: int, not_in=(), timeout_s: float = 30.0) -> int:
    """The zygote's spare child: its one living child once the previous reader has gone."""
    limit = time.monotonic() + timeout_s
    while time.monotonic() < limit:
        kids = [k for k in _alive_children(zygote_pid) if k not in not_in]
        if len(kids) == 1:
            return kids[0]
        time.sleep(0.02)
    raise AssertionError(f"no single spare child of the zygote: {_alive_children(zygote_pid)}")


def test_the_read_is_served_by_the_spare_forked_ahead_and_a_new_spare_follows(ready):
    served = []
    for _ in range(3):
        spare = _spare(ready, not_in=served)
        pid = _call(os.getpid)
        assert pid == spare  # the child forked before the request served it
        served.append(pid)
    assert len(set(served)) == 3  # one child per read
    assert _spare(ready, not_in=served) not in served  # and the next one waits already


def test_a_crash_leaves_the_next_read_to_a_new_spare(ready):
    crashed = _spare(ready)
    with pytest.raises(MeshError) as err:
        _call(ctypes.string_at, 0)  # a segfault in the spare that took the read
    assert str(err.value) == crash_sentence(PATH)
    spare = _spare(ready, not_in=[crashed])
    assert _call(os.getpid) == spare
    assert zygote.pid() == ready


def test_a_dead_spare_is_replaced_by_a_fresh_child(ready):
    spare = _spare(ready)
    os.kill(spare, signal.SIGKILL)
    time.sleep(0.1)
    pid = _call(os.getpid)
    assert pid != spare
    assert _call(os.getppid) == ready  # still the zygote's children, the zygote unharmed
    assert zygote.pid() == ready


def _limits():
    import resource

    usage = resource.getrusage(resource.RUSAGE_SELF)
    return (
        resource.getrlimit(resource.RLIMIT_AS)[0],
        resource.getrlimit(resource.RLIMIT_CPU)[0],
        (usage.ru_utime + usage.ru_stime),
    )


def _statm_bytes():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")


def _where():
    return os.getppid(), os.getcwd(), os.environ.get("MAGNET_TEST_SPARE"), os.environ.get("PATH")


def test_a_spare_reads_under_this_reads_limits_environment_and_folder(ready, monkeypatch, tmp_path):
    assert _call(os.getppid) == ready  # functions of this module are served by the zygote's children
    address, cpu, used = _call(_limits, timeout_s=7)
    size = _call(_statm_bytes)
    assert size < address <= size + (1 << 30) + (64 << 20)  # RLIMIT_AS: this read's memory_bytes on top
    assert used + 7 <= cpu <= used + 7 + 3  # RLIMIT_CPU: this read's deadline (+2 s), from now
    with pytest.raises(MeshError) as err:  # and they hold, read after read
        _call(bytearray, 8 << 30)
    assert str(err.value) == memory_sentence(PATH, 1 << 30)
    with pytest.raises(MeshError) as err:
        _call(time.sleep, 60, timeout_s=1)
    assert str(err.value) == timeout_sentence(PATH, 1)
    monkeypatch.setenv("MAGNET_TEST_SPARE", "yes")
    monkeypatch.delenv("PATH")  # the zygote has one: gone for this read
    monkeypatch.chdir(tmp_path)
    assert _call(_where) == (ready, str(tmp_path), "yes", None)


def test_the_answer_comes_straight_from_the_child_and_the_zygotes_word_follows(ready):
    z = zygote.acquire(start=False)
    assert z is not None
    zygote.release(z)
    assert _call(os.getppid) == ready
    assert z.owed  # answered on our own pipe: the zygote's "done" not taken yet
    with pytest.raises(MeshError) as err:  # the next read takes it first, and its crash is worded
        _call(ctypes.string_at, 0)
    assert str(err.value) == crash_sentence(PATH)
    assert not z.owed
    assert _call(os.getppid) == ready and zygote.pid() == ready


def _announced(timeout_s: float = 30.0) -> int:
    """The pid of the spare the zygote announced to this process (its request socket with it)."""
    z = zygote.acquire(start=False)
    assert z is not None
    try:
        limit = time.monotonic() + timeout_s
        while time.monotonic() < limit:
            z._direct_poll()
            if z.spare is not None:
                return z.spare[0]
            time.sleep(0.02)
    finally:
        zygote.release(z)
    raise AssertionError("no spare announced")


def test_the_request_goes_straight_to_the_announced_spare_and_the_zygote_watches_it(ready):
    """The zygote announces each spare (its pid and request socket): the caller hands the request
    to it without the zygote's hop, and tells the zygote, which still enforces the deadline and
    words the end; a dead announced spare sends the request the zygote's way."""
    z = zygote.acquire(start=False)
    handed = z.used
    zygote.release(z)
    for _ in range(3):
        spare = _announced()
        assert _call(os.getpid) == spare
    assert z.used == handed  # none went through the zygote's hands
    spare = _announced()
    with pytest.raises(MeshError) as err:  # the zygote's deadline and wording, for a direct request
        _call(time.sleep, 30, timeout_s=1)
    assert str(err.value) == timeout_sentence(PATH, 1)
    spare = _announced()
    os.kill(spare, signal.SIGKILL)
    time.sleep(0.1)
    pid = _call(os.getpid)
    assert pid != spare and z.used == pid  # a fresh child, through the zygote
    assert zygote.pid() == ready
