"""The sandboxed read's answer, written and taken back, against the pickle it replaced (round six,
docs/benchmarks.md): the same Mesh, the same fresh memfd per run, alternating, in this process.

  pickle: protocol 5, every array out of band, 64-byte aligned, mapped shared and populated
          (models/mesh/sandbox.py and zygote.py before round six, kept here as the baseline)
  raw:    models.mesh.answer (JSON header, raw arrays; the caller seals the memfd, checks the
          header and the Mesh's invariants, maps it private: populated read-only, copy-on-write)

Columns: best / median ms of --repeat, and raw / pickle of the bests.

  python bench/bench_answer_codec.py [--n 24] [--repeat 30]
"""

from __future__ import annotations

import argparse
import mmap
import os
import pickle
import statistics
import struct
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [os.path.dirname(HERE), HERE, os.path.join(os.path.dirname(HERE), "tests")]
_ALIGN = 64


def pickle_dump(answer, shm: int) -> None:
    buffers = []
    data = pickle.dumps(answer, protocol=5, buffer_callback=buffers.append)
    raws = [b.raw() for b in buffers]
    head = struct.pack(f"<QQ{len(raws)}Q", len(data), len(raws), *(m.nbytes for m in raws))
    with os.fdopen(os.dup(shm), "wb", buffering=0) as out:
        pos = 0
        for chunk in (head, data, *raws):
            pad = -pos % _ALIGN
            if pad:
                out.write(b"\0" * pad)
                pos += pad
            view = memoryview(chunk).cast("B")
            while view.nbytes:
                n = out.write(view)
                view, pos = view[n:], pos + n


def pickle_load(shm: int):
    size = os.fstat(shm).st_size
    flags = mmap.MAP_SHARED | getattr(mmap, "MAP_POPULATE", 0)
    mem = mmap.mmap(shm, size, flags=flags, prot=mmap.PROT_READ | mmap.PROT_WRITE)
    view = memoryview(mem)
    n_data, n_bufs = struct.unpack_from("<QQ", view, 0)
    lengths = struct.unpack_from(f"<{n_bufs}Q", view, 16)
    pos = 16 + 8 * n_bufs
    pos += -pos % _ALIGN
    data = view[pos : pos + n_data]
    pos += n_data
    bufs = []
    for n in lengths:
        pos += -pos % _ALIGN
        bufs.append(view[pos : pos + n])
        pos += n
    return pickle.loads(data, buffers=bufs)  # noqa: S301  (the baseline: the hole round six closed)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=24)
    ap.add_argument("--repeat", type=int, default=30)
    a = ap.parse_args()

    from bench_read_formats import corpus

    from models.mesh import answer
    from models.mesh.read import read_mesh

    folder = tempfile.mkdtemp(prefix="magnet-codec-")
    print(f"# answer codec, best / median of {a.repeat}, ms; a fresh memfd per run")
    print(
        "| file | cells | pickle dump | raw dump | pickle load | raw load | dump raw/pickle | load raw/pickle |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for label, path, cells in corpus(folder, a.n):
        if not any(k in label for k in ("binary", "VTI", "VTU appended")):
            continue
        mesh = read_mesh(path)
        t = {"pickle dump": [], "raw dump": [], "pickle load": [], "raw load": []}
        for _ in range(a.repeat):
            for kind, dump, load in (("pickle", pickle_dump, pickle_load), ("raw", answer.dump, answer.load)):
                fd = os.memfd_create("codec", os.MFD_CLOEXEC | os.MFD_ALLOW_SEALING)
                s = time.perf_counter()
                dump(("ok", mesh), fd)
                t[kind + " dump"].append(time.perf_counter() - s)
                s = time.perf_counter()
                got = load(fd)
                t[kind + " load"].append(time.perf_counter() - s)
                assert got[0] == "ok"
                del got
                os.close(fd)
        cols = " | ".join(f"{min(v) * 1e3:.2f} / {statistics.median(v) * 1e3:.2f}" for v in t.values())
        dr = min(t["raw dump"]) / min(t["pickle dump"])
        lr = min(t["raw load"]) / min(t["pickle load"])
        print(f"| {label} | {cells:,} | {cols} | {dr:.2f} | {lr:.2f} |")


if __name__ == "__main__":
    main()
