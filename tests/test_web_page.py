"""The web page at `/` in a real browser: Debian's chromium driven by Playwright for Python, against
a real server with its embedded worker. Uploads the brain through the page, runs METIS jobs, follows
the progress to 100% (server-sent events), looks at the result (SVG, picture, box plots), downloads
the VTU, compares two jobs, deletes one; and the same with API keys on.

scripts/test.sh installs chromium (`apt-get install chromium chromium-driver`); without it, or
without the playwright package, the tests are skipped with the reason."""

from __future__ import annotations

import base64
import os
import shutil

import httpx
import pytest
from service_fixtures import BRAIN, service_env, start_api, wait_until, workers_online

pytestmark = pytest.mark.slow
sync_api = pytest.importorskip(
    "playwright.sync_api", reason="playwright is not installed (pip install playwright)"
)
CHROMIUM = os.environ.get("MAGNET_TEST_CHROMIUM", "/usr/bin/chromium")
ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
KEYS = "alice:alice-token,bob:bob-token"


@pytest.fixture(scope="module")
def browser():
    if not (os.path.exists(CHROMIUM) or shutil.which(CHROMIUM)):
        pytest.skip(
            f"no chromium at {CHROMIUM} (apt-get install chromium chromium-driver; scripts/test.sh does)"
        )
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield b
        b.close()


def serve(tmp_path, **env):
    proc, url = start_api(service_env(tmp_path / "data", **env), tmp_path, embedded_worker=True)
    token = (env.get("api_keys") or ":").split(",")[0].split(":")[1] or None
    wait_until(lambda: workers_online(url, token) >= 1, 60, 0.2, "the embedded worker")
    return proc, url


def until(page, expression: str, timeout_ms: int = 30_000):
    """Poll a JavaScript expression until it is truthy. (Playwright's wait_for_function compiles its
    predicate with eval, which the page's Content-Security-Policy forbids: evaluate is not.)"""
    return wait_until(lambda: page.evaluate(expression), timeout_ms / 1000, 0.1, expression)


def new_page(browser, url):
    context = browser.new_context(viewport={"width": 1280, "height": 900}, accept_downloads=True)
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.on("console", lambda m: "Content Security Policy" in m.text and errors.append(m.text))
    page.goto(url + "/")
    return page, errors


def upload_brain(page):
    page.set_input_files("#file", str(BRAIN))
    page.wait_for_selector("#mesh-summary")
    assert "14372" in page.inner_text("#mesh-summary")
    assert "verdict ok" in page.inner_text("#mesh-check")  # the upload's `check` report


def kway(page, model: str, k: str):
    """The form set for `model` in k-way mode with k elements."""
    page.select_option("select[name=model]", model)
    page.select_option("select[name=mode]", "kway")
    page.fill("input[name=k]", k)


def drop_brain(page):
    """Drag and drop: a `drop` event carrying the file, as a browser fires it."""
    page.evaluate(
        """([name, b64]) => {
        const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
        const transfer = new DataTransfer();
        transfer.items.add(new File([bytes], name));
        const zone = document.querySelector('#drop');
        for (const type of ['dragover', 'drop'])
          zone.dispatchEvent(new DragEvent(type, {dataTransfer: transfer, bubbles: true, cancelable: true}));
        }""",
        [BRAIN.name, base64.b64encode(BRAIN.read_bytes()).decode()],
    )
    page.wait_for_selector("#mesh-summary")
    assert "14372" in page.inner_text("#mesh-summary")


def run_job(page, timeout_ms: int = 120_000) -> list[str]:
    """Submit the form; returns every percentage the progress line showed, up to 100%."""
    page.evaluate(
        """() => { window.seenProgress = [];
        new MutationObserver(() => window.seenProgress.push(document.querySelector('#progress-pct').textContent))
          .observe(document.querySelector('#progress-pct'), {childList: true, characterData: true, subtree: true}); }"""
    )
    page.click("button[type=submit]")
    until(page, "document.querySelector('#progress-pct').textContent === '100%'", timeout_ms=timeout_ms)
    until(page, "document.querySelector('#progress-status').textContent === 'succeeded'")
    return page.evaluate("window.seenProgress")


def test_progress_is_shown_live(browser, tmp_path):
    """The progress line moves while a job runs, not only from 0% to 100%. The server sends a job's
    state every 0.25 s and the worker writes none in a job's first 0.1 s, so a job of the 14k-cell
    brain (well under a second) could end between two sends: a mesh of 180k triangles here."""
    import meshio
    import numpy as np

    n = 300
    x, y = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    pts = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()
    tris = np.concatenate(
        [np.column_stack([a, a + n + 1, a + n + 2]), np.column_stack([a, a + n + 2, a + 1])]
    )
    big = tmp_path / "plate.vtu"
    meshio.write(str(big), meshio.Mesh(pts, [("triangle", tris)]))
    proc, url = serve(tmp_path)
    try:
        page, errors = new_page(browser, url)
        page.set_input_files("#file", str(big))
        page.wait_for_selector("#mesh-summary")
        assert f"{len(tris)}" in page.inner_text("#mesh-summary")
        kway(page, "metis", "512")
        seen = run_job(page)
        assert seen[-1] == "100%" and any(0 < int(v[:-1]) < 100 for v in seen), seen  # live, not only the end
        assert errors == []
    finally:
        proc.stop()


def test_page_uploads_runs_metis_shows_and_downloads(browser, tmp_path):
    import meshio

    proc, url = serve(tmp_path)
    try:
        page, errors = new_page(browser, url)
        upload_brain(page)
        # the API's validation errors appear next to the field: the library's, then pydantic's
        kway(page, "metis", "99999")
        page.click("button[type=submit]")
        page.wait_for_selector(".field[data-field=k].invalid")
        assert "larger than the number of cells" in page.inner_text(".field[data-field=k] .error")
        page.fill("input[name=k]", "0")
        page.click("button[type=submit]")
        until(page, "document.querySelector('.field[data-field=k] .error').textContent.includes('1')")
        page.fill("input[name=k]", "64")
        seen = run_job(page)
        assert seen[-1] == "100%", seen  # (live progress on a job long enough to show it: the next test)
        # the result: picture, SVG with one path per element, hover metrics, colour by a metric, box plots
        until(page, "document.querySelector('#preview').naturalWidth > 0")
        until(page, "document.querySelectorAll('#mesh-svg path').length === 64")
        page.hover("#mesh-svg path[data-e='5']")
        tip = page.inner_text("#tip")
        assert "element 5" in tip and "circle_ratio" in tip
        page.select_option("#color-by", "circle_ratio")
        assert page.locator("#legend .ramp").count() == 1
        # one box per metric of the job's summary (read from the API, not hard-coded: metrics get added)
        done = [
            j for j in httpx.get(url + "/v1/jobs", timeout=10).json()["items"] if j["status"] == "succeeded"
        ]
        summary = httpx.get(f"{url}/v1/jobs/{done[0]['id']}/metrics", timeout=10).json()["summary"]
        assert len(summary) >= 4 and "circle_ratio" in summary
        assert page.locator("#boxplots svg.boxplot g.box").count() == len(summary)
        assert "64" in page.inner_text("#partition")
        with page.expect_download() as info:
            page.click("#downloads a:text-is('mesh.vtu')")
        target = tmp_path / "downloaded.vtu"
        info.value.save_as(target)
        assert info.value.suggested_filename.endswith("mesh.vtu")
        assert sum(len(block.data) for block in meshio.read(target).cells) == 64
        # a second job of the same mesh, then compare the two side by side
        page.fill("input[name=k]", "32")
        run_job(page)
        rows = page.locator("#job-rows tr[data-job]")
        wait_until(lambda: rows.count() == 2 and "64" in page.inner_text("#job-rows"), 20, 0.2, "two rows")
        for i in range(2):
            rows.nth(i).locator("input[type=checkbox]").check()
        page.click("#compare-button")
        until(
            page,
            "[...document.querySelectorAll('#compare-pictures img')].filter(i => i.naturalWidth > 0).length === 2",
        )
        plots = page.locator("#compare-plots svg.boxplot")
        # a plot per metric, two boxes (jobs) in each
        assert plots.count() == len(summary) and plots.first.locator("g.box").count() == 2
        # delete one: gone from the list and from the API
        job_id = rows.nth(1).get_attribute("data-job")
        rows.nth(1).locator("button[data-act=delete]").click()
        wait_until(lambda: page.locator("#job-rows tr[data-job]").count() == 1, 20, 0.2, "the row to go")
        assert page.request.get(f"{url}/v1/jobs/{job_id}").status == 404
        assert errors == []
    finally:
        proc.stop()


def test_page_with_api_keys(browser, tmp_path):
    proc, url = serve(tmp_path, api_keys=KEYS)
    try:
        page, errors = new_page(browser, url)
        page.wait_for_selector("#notice:not([hidden])")
        assert "API key" in page.inner_text("#notice")
        page.fill("#token", "wrong-token")
        page.locator("#token").blur()
        until(page, "document.querySelector('#job-rows').textContent.includes('invalid API key')")
        page.fill("#token", "alice-token")
        page.locator("#token").blur()
        page.wait_for_selector("#notice", state="hidden")
        drop_brain(page)
        page.fill("input[name=k]", "16")
        run_job(page)
        until(page, "document.querySelector('#preview').naturalWidth > 0")
        with page.expect_download() as info:
            page.click("#downloads a:text-is('labels.json')")
        assert len(open(info.value.path()).read()) > 14372  # one label per fine cell
        # the key is kept in the browser: a reload shows alice's job again
        page.reload()
        assert page.input_value("#token") == "alice-token"
        page.wait_for_selector("#job-rows tr[data-job]")
        assert page.locator("#job-rows tr[data-job]").count() == 1
        # bob sees none of it
        page.fill("#token", "bob-token")
        page.locator("#token").blur()
        page.wait_for_selector("#job-rows td.hint")
        assert errors == []
    finally:
        proc.stop()


def test_page_builds_a_hierarchy_and_shows_every_level(browser, tmp_path):
    import io
    import json
    import zipfile

    proc, url = serve(tmp_path)
    try:
        page, errors = new_page(browser, url)
        upload_brain(page)
        kway(page, "rtree", "512")  # the job's 512 elements are the finest level
        assert page.locator(".field[data-field=ratio]").is_hidden()
        page.check("input[name=hierarchy]")
        assert page.inner_text("#submit") == "Build hierarchy"
        # the API's validation of the hierarchy fields shows next to them
        page.fill("input[name=ratio]", "1")
        page.click("#submit")
        page.wait_for_selector(".field[data-field=ratio].invalid")
        page.fill("input[name=ratio]", "8")
        page.fill("input[name=coarsest]", "10")
        seen = run_job(page)
        assert seen[-1] == "100%"
        job_id = until(page, "document.querySelector('#hierarchy').dataset.job")
        assert "hierarchy ratio 8" in page.inner_text("#job-rows")
        # what the API says the hierarchy is: hierarchy.json in the zip
        r = httpx.get(f"{url}/v1/jobs/{job_id}/hierarchy", timeout=30)
        index = json.loads(zipfile.ZipFile(io.BytesIO(r.content)).read("hierarchy.json"))
        counts = [lv["elements"] for lv in index["levels"]]
        assert len(counts) >= 3 and counts == sorted(counts) and counts[0] <= 10 and counts[-1] == 512
        # every level drawn, one over the other, coarsest on top: its count, one path per element
        until(
            page,
            f"document.querySelectorAll('#levels .level svg.level-svg').length === {len(counts)}",
            60_000,
        )
        levels = page.locator("#levels .level")
        assert levels.count() == len(counts)
        tops = []
        for L, n in enumerate(counts):
            level = levels.nth(L)
            assert level.get_attribute("data-level") == str(L)
            assert level.locator("h3 .count").inner_text() == str(n)
            assert level.locator("svg .fills path").count() == n
            assert level.locator("td[data-metric=elements]").inner_text() == str(n)
            assert float(level.locator("td[data-metric='circle ratio (median)']").inner_text()) > 0
            # over the fine mesh (its 14372 cells), with the next coarser level's outlines on top
            assert (
                page.evaluate(
                    f"document.querySelectorAll('#levels .level')[{L}].querySelector('path.fine').getAttribute('d').split('Z').length - 1"
                )
                == 14372
            )
            assert level.locator("svg path.coarser").count() == (1 if L > 0 else 0)
            tops.append(level.bounding_box()["y"])
        assert tops == sorted(tops) and len(set(tops)) == len(tops)  # stacked vertically
        page.hover("#levels .level:last-child svg .fills path[data-e='3']")
        assert f"level {len(counts) - 1}, element 3" in page.inner_text("#tip")
        with page.expect_download() as info:
            page.click("#hierarchy-download a")
        assert info.value.suggested_filename.endswith("hierarchy.zip")
        assert "hierarchy.json" in zipfile.ZipFile(info.value.path()).namelist()
        # 3D: each level's picture (the exploded view, as a 3D job's preview), one over the other
        import meshio
        from meshes import tets

        cube = tmp_path / "cube.vtu"
        meshio.write(cube, meshio.Mesh(*tets(4)[:1], [("tetra", tets(4)[1])]))
        page.set_input_files("#file", str(cube))
        until(page, "document.querySelector('#mesh-summary').textContent.includes('384')")
        page.select_option("select[name=model]", "rtree")
        page.fill("input[name=k]", "8")
        page.fill("input[name=ratio]", "4")
        page.fill("input[name=coarsest]", "6")
        run_job(page)
        until(page, f"(d => d && d !== '{job_id}')(document.querySelector('#hierarchy').dataset.job)")
        cube_id = page.evaluate("document.querySelector('#hierarchy').dataset.job")
        counts = [
            lv["elements"]
            for lv in httpx.get(f"{url}/v1/jobs/{cube_id}/hierarchy/levels", timeout=30).json()["levels"]
        ]
        assert len(counts) >= 2
        until(
            page,
            f"[...document.querySelectorAll('#levels .level img')].filter(i => i.naturalWidth > 0).length === {len(counts)}",
            60_000,
        )
        assert [page.locator("#levels .level h3 .count").nth(L).inner_text() for L in range(len(counts))] == [
            str(n) for n in counts
        ]
        assert errors == []
    finally:
        proc.stop()


def test_page_hierarchy_finest_level_choice(browser, tmp_path):
    """The finest-level choice of `magnet hierarchy --finest` on the page: an aggregated finest level takes
    the default schedule (the ratio field goes away and no ratio is sent), and hierarchy.json says so."""
    import io
    import json
    import zipfile

    proc, url = serve(tmp_path)
    try:
        page, errors = new_page(browser, url)
        upload_brain(page)
        kway(page, "rtree", "64")
        assert page.locator(".field[data-field=finest]").is_hidden()
        page.check("input[name=hierarchy]")
        assert page.locator(".field[data-field=ratio]").is_visible()
        page.select_option("select[name=finest]", "aggregation")
        assert page.locator(".field[data-field=ratio]").is_hidden()
        page.fill("input[name=coarsest]", "10")
        run_job(page)
        job_id = until(page, "document.querySelector('#hierarchy').dataset.job")
        assert "finest aggregation" in page.inner_text("#job-rows")
        job = httpx.get(f"{url}/v1/jobs/{job_id}", timeout=30).json()
        options = job["params"]["options"]
        assert options["finest"] == "aggregation" and options.get("ratio") is None
        r = httpx.get(f"{url}/v1/jobs/{job_id}/hierarchy", timeout=30)
        index = json.loads(zipfile.ZipFile(io.BytesIO(r.content)).read("hierarchy.json"))
        assert index["finest"] == "aggregation"
        counts = [lv["elements"] for lv in index["levels"]]
        # levels of their own from the cells: the finest about 14372 / 5 triangles, not the job's 64
        assert counts == sorted(counts) and counts[0] <= 10 and 2000 < counts[-1] < 5000
        assert errors == []
    finally:
        proc.stop()
