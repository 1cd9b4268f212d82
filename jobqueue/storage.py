"""Blobs under the data directory: meshes content-addressed by sha256, results by result key.

Layout: meshes/ab/<sha256>.<ext>, results/<result_key>/{mesh.vtu, metrics.json, ..., summary.json},
tmp/ for uploads and running jobs. A result directory appears atomically (rename) and only complete.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import uuid
from pathlib import Path

SUMMARY = "summary.json"


class Storage:
    """The data directory (a shared volume when API and workers run on different hosts)."""

    def __init__(self, root: Path | str):
        self.root = Path(root).resolve()
        for sub in ("meshes", "results", "tmp"):
            (self.root / sub).mkdir(parents=True, exist_ok=True)

    def mesh_path(self, mesh_id: str, ext: str) -> Path:
        return self.root / "meshes" / mesh_id[:2] / f"{mesh_id}.{ext}"

    def temp_file(self, name: str) -> Path:
        """A new empty file called `name` in a private temp directory (remove with discard_temp)."""
        folder = Path(tempfile.mkdtemp(dir=self.root / "tmp", prefix="upload-"))
        path = folder / name
        path.touch()
        return path

    @staticmethod
    def discard_temp(path: Path) -> None:
        shutil.rmtree(path.parent, ignore_errors=True)

    def put_mesh(self, temp: Path, mesh_id: str, ext: str) -> Path:
        """Move an uploaded temp file into its content-addressed place (a no-op when present)."""
        dest = self.mesh_path(mesh_id, ext)
        if dest.exists():
            temp.unlink(missing_ok=True)
        else:
            dest.parent.mkdir(parents=True, exist_ok=True)
            os.replace(temp, dest)
        return dest

    def result_dir(self, result_key: str) -> Path:
        return self.root / "results" / result_key

    def has_result(self, result_key: str) -> bool:
        return (self.result_dir(result_key) / SUMMARY).exists()

    def read_summary(self, result_key: str) -> dict:
        return json.loads((self.result_dir(result_key) / SUMMARY).read_text())

    def work_dir(self, job_id: str) -> Path:
        """A fresh private directory for one attempt at a job."""
        path = self.root / "tmp" / f"job-{job_id}-{uuid.uuid4().hex[:8]}"
        path.mkdir(parents=True)
        return path

    def publish_result(self, work_dir: Path, result_key: str, summary: dict) -> None:
        """Make a finished work directory the result for result_key; the first publisher wins."""
        files = [p for p in work_dir.rglob("*") if p.is_file()]
        summary = {**summary, "result_bytes": sum(p.stat().st_size for p in files)}
        (work_dir / SUMMARY).write_text(json.dumps(summary, default=_plain))
        dest = self.result_dir(result_key)
        try:
            os.rename(work_dir, dest)
        except OSError:
            if not self.has_result(result_key):
                # a stale incomplete directory (never published): replace it
                shutil.rmtree(dest, ignore_errors=True)
                os.rename(work_dir, dest)
            else:
                shutil.rmtree(work_dir, ignore_errors=True)

    def result_bytes(self, result_key: str) -> int:
        """Bytes of a published result (from its summary; measured for results older than that)."""
        try:
            known = self.read_summary(result_key).get("result_bytes")
        except (OSError, ValueError):
            return 0
        if known is None:
            known = sum(p.stat().st_size for p in self.result_dir(result_key).rglob("*") if p.is_file())
        return int(known)

    def check_writable(self) -> None:
        probe = self.root / "tmp" / f".probe-{uuid.uuid4().hex}"
        probe.write_bytes(b"ok")
        probe.unlink()


def _plain(value):
    """json default for numpy scalars and arrays."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if hasattr(value, "item"):
        return value.item()
    raise TypeError(f"not JSON serializable: {type(value).__name__}")
