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
