"""Take the web page's screenshots in docs/ (README, "Web page"): a real server with its embedded
worker, Debian's chromium driven by Playwright, the brain mesh (and a hierarchy of it).

    PYTHONPATH=. .venv/bin/python scripts/web_screenshots.py [OUT_DIR]

The PNGs are reduced to a 96-colour palette to stay small.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import meshio  # noqa: E402
from meshes import tets  # noqa: E402
from PIL import Image  # noqa: E402
from playwright.sync_api import sync_playwright  # noqa: E402
from service_fixtures import BRAIN, service_env, start_api, wait_until, workers_online  # noqa: E402

ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run"]  # fmt: skip


def until(page, expression: str, timeout_ms: int = 30_000):
    """Poll a JavaScript expression until it is truthy. (Playwright's wait_for_function compiles its
    predicate with eval, which the page's Content-Security-Policy forbids: evaluate is not.)"""
    return wait_until(lambda: page.evaluate(expression), timeout_ms / 1000, 0.1, expression)


def save(page, path: Path, selector: str | None = None) -> None:
    (page.locator(selector) if selector else page).screenshot(path=str(path))
    Image.open(path).convert("RGB").quantize(96, method=Image.Quantize.MEDIANCUT).save(path, optimize=True)
    print(f"{path} {path.stat().st_size // 1024} KiB")


def submit(page, model: str, mode: str, field: str, value: str) -> None:
    page.select_option("select[name=model]", model)
    page.select_option("select[name=mode]", mode)
    page.fill(f"[name={field}]", value)
    page.click("button[type=submit]")


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="magnet-shots-"))
    proc, url = start_api(service_env(tmp / "data"), tmp, embedded_worker=True)
    try:
        wait_until(lambda: workers_online(url) >= 1, 60, 0.2, "the embedded worker")
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=ARGS)
            page = browser.new_page(viewport={"width": 1300, "height": 760})
            page.goto(url + "/")
            page.set_input_files("#file", str(BRAIN))
            page.wait_for_selector("#mesh-summary")
            page.fill("[name=k]", "99999")
            page.click("button[type=submit]")
            page.wait_for_selector(".field[data-field=k].invalid")
            save(page, out / "web-upload.png", ".left")
            page.fill("[name=k]", "64")
            page.click("button[type=submit]")
            until(
                page, "(t => t > 0 && t < 100)(parseInt(document.querySelector('#progress-pct').textContent))"
            )
            save(page, out / "web-progress.png", ".left")
            until(page, "document.querySelector('#progress-pct').textContent === '100%'")
            until(page, "document.querySelector('#preview').naturalWidth > 0")
            page.wait_for_selector("#mesh-svg path")
            page.select_option("#color-by", "circle_ratio")
            page.hover("#mesh-svg path[data-e='20']")
            save(page, out / "web-result.png", "#result")
            for model, mode, field, value in (("kmeans", "kway", "k", "64"), ("metis", "nref", "nref", "6")):
                submit(page, model, mode, field, value)
                until(page, "document.querySelector('#progress-status').textContent === 'succeeded'")
                page.wait_for_timeout(500)
            wait_until(lambda: page.locator("#job-rows tr.succeeded").count() == 3, 30, 0.2, "three jobs")
            for i in range(3):
                page.locator("#job-rows tr.succeeded input[type=checkbox]").nth(i).check()
            page.click("#compare-button")
            until(
                page, "[...document.querySelectorAll('#compare-pictures img')].every(i => i.naturalWidth > 0)"
            )
            save(page, out / "web-compare.png", "#compare")
            page.mouse.move(0, 0)
            save(page, out / "web-jobs.png", "#jobs")
            # a hierarchy: every level one over the other, over the fine mesh
            page.check("[name=hierarchy]")
            page.fill("[name=ratio]", "8")
            page.fill("[name=coarsest]", "10")
            submit(page, "rtree", "kway", "k", "64")
            until(page, "document.querySelector('#progress-status').textContent === 'succeeded'")
            until(page, "document.querySelectorAll('#levels svg.level-svg').length >= 3", 60_000)
            page.mouse.move(0, 0)
            save(page, out / "web-hierarchy.png", "#hierarchy")
            page.uncheck("[name=hierarchy]")
            # a 3D job: the exploded-view picture instead of the SVG
            cube = tmp / "cube.vtu"
            meshio.write(cube, meshio.Mesh(*tets(8)[:1], [("tetra", tets(8)[1])]))
            page.set_input_files("#file", str(cube))
            page.wait_for_selector("#mesh-summary")
            submit(page, "metis", "kway", "k", "12")
            until(page, "document.querySelector('#progress-status').textContent === 'succeeded'")
            until(
                page,
                "document.querySelector('#drawing').hidden && document.querySelector('#preview').naturalWidth > 0",
            )
            until(page, "document.querySelector('#result-title').textContent.includes('k=12')")
            save(page, out / "web-result-3d.png", "#result")
            browser.close()
    finally:
        proc.stop()


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs")
