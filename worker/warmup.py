"""MAGNET_PRELOAD_MODELS (`magnet worker --preload-models`): each pool process loads the shipped
networks and runs one tiny neural job (a 4 x 4 square) when it starts, so its first real job pays
no import or weight load. Either way a process keeps what it loaded for its whole life (up to
worker_max_tasks_per_child jobs): networks are never reloaded per job."""

from __future__ import annotations

import logging
import tempfile
import time
from pathlib import Path

from celery import signals

from jobqueue.settings import Settings

log = logging.getLogger("magnet.worker")


def warm_up() -> list[str]:
    """Load every network and run the library once end to end; returns the networks loaded."""
    import meshio
    import numpy as np

    from models import api
    from models.partition.sage import warm_up as load_networks

    loaded = load_networks()
    xs = np.linspace(0.0, 1.0, 5)
    x, y = np.meshgrid(xs, xs)
    points = np.c_[x.ravel(), y.ravel(), np.zeros(x.size)]
    a = (np.arange(4)[None, :] + 5 * np.arange(4)[:, None]).ravel()
    triangles = np.r_[np.c_[a, a + 1, a + 6], np.c_[a, a + 6, a + 5]]
    with tempfile.TemporaryDirectory(prefix="magnet-warmup-") as tmp:
        mesh = Path(tmp) / "square.vtu"
        meshio.write(str(mesh), meshio.Mesh(points, [("triangle", triangles)]))
        api.run_job(str(mesh), str(Path(tmp) / "out"), {"model": "sage-base", "mode": "nref", "nref": 2})
    return loaded


@signals.worker_process_init.connect
def _warm_up(**_):
    if not Settings().preload_models:
        return
    t0 = time.perf_counter()
    try:
        loaded = warm_up()
    except Exception as exc:  # a failed warm-up only costs the first job its speed
        log.warning("preloading the networks failed: %s", exc)
        return
    log.info("preloaded %s and ran a warm-up job in %.2f s", ", ".join(loaded), time.perf_counter() - t0)
