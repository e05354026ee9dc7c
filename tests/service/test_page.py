"""The jobs page ``GET /`` in headless Chromium (driven by Playwright against the real
server): with a token set, the page says so; given the token it offers every process of
the service (the registry is the oracle), builds each one's form from its description,
shows an API error as its problem's title and detail, uploads the bundled tree and runs
it, starts a reconstruction from the same upload (reused, not sent again) with settings
changed in the generated form (the job on the server holds exactly those values),
dismisses that job (gone from the list), lists a finished job's files, embeds its report
with the 3D view, and opens the report. The page loads nothing from outside, runs under
a Content-Security-Policy without inline script, and logs no error."""

from __future__ import annotations

import re
import zipfile
from pathlib import Path

import httpx
import pytest

from tests.report.browser import chromium
from treesim.plot import Plot, PlotTree
from treesim.plot.io import write_plot
from treesim.service.problems import PROBLEMS
from treesim.service.processes import PROCESSES

from .conftest import BUNDLED_CLOUD

pytestmark = pytest.mark.slow

TOKEN = "page-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def _watch(page, base: str, outside: list[str], errors: list[str]) -> None:
    """Record requests that leave the origin, script errors, console errors and HTTP
    errors (a 401 before the token is given is by design: not an error)."""
    page.on("request", lambda r: None if r.url.startswith(base) else outside.append(r.url))
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on(
        "console",
        lambda m: (
            errors.append(m.text) if m.type == "error" and "status of 401" not in m.text else None
        ),
    )
    page.on(
        "response",
        lambda r: (
            errors.append(f"{r.status} {r.url}") if r.status >= 400 and r.status != 401 else None
        ),
    )


def _sign_in(page, base: str, sync_api) -> None:
    page.goto(base + "/")
    # without the token the API answers 401 and the page says what is missing
    sync_api.expect(page.locator("#token-state")).to_contain_text("token", timeout=10_000)
    page.fill("#token", TOKEN)
    page.click("#token-save")
    sync_api.expect(page.locator("#token-state")).to_have_text("", timeout=10_000)


def _api_error_is_shown(page, sync_api) -> str:
    """A plan with neither plot, mesh nor stand: the server's 422 problem, shown as its
    title and detail. Returns the refused request's URL."""
    page.select_option("#process", "plan")
    sync_api.expect(page.locator("#submit")).to_have_text("Run plan")
    with page.expect_response(lambda r: r.url.endswith("/processes/plan/execution")) as got:
        page.click("#submit")
    problem = got.value.json()
    assert got.value.status == 422 and problem["title"] == PROBLEMS["invalid-parameter"].title
    sync_api.expect(page.locator("#message")).to_have_text(
        f"{problem['title']}: {problem['detail']}"
    )
    assert page.locator("#message").get_attribute("class") == "error"
    # the field the problem names is outlined
    assert problem["field"] == "inputs.plot"
    assert page.locator('#process-form .invalid[data-path="plot"]').count() == 1
    return got.value.url


def _run_uploaded_tree(page, base: str, sync_api) -> str:
    """``run`` with preset draft on a new upload of the bundled tree: its job id."""
    page.select_option("#process", "run")
    sync_api.expect(page.locator("#set-preset")).to_be_visible()
    page.select_option("#set-preset", label="draft")
    assert page.locator("#in-cloud").input_value() == "new"  # nothing uploaded yet
    page.set_input_files("#new-cloud", str(BUNDLED_CLOUD))
    page.click("#submit")
    sync_api.expect(page.locator("#message")).to_contain_text("accepted", timeout=30_000)
    (job,) = httpx.get(f"{base}/v1/jobs", headers=AUTH).json()["jobs"]
    assert job["processID"] == "run" and job["parameters"] == {"preset": "draft"}
    row = page.locator(f'#jobs tr[data-job="{job["jobID"]}"]')
    sync_api.expect(row).to_have_attribute("data-status", "successful", timeout=240_000)
    assert row.locator("progress").get_attribute("value") == "100"
    assert "cloud: cloud.txt" in row.inner_text()
    return job["jobID"]


def _reconstruct_reusing_the_upload(page, base: str, sync_api, run_id: str) -> str:
    """``reconstruct`` of the same upload, with an enum, a number, a boolean and a nested
    integer changed in the generated form: the job on the server holds exactly these."""
    uploads = httpx.get(f"{base}/v1/uploads", headers=AUTH).json()["uploads"]
    (upload,) = [u for u in uploads if u["filename"] == "cloud.txt"]
    page.select_option("#process", "reconstruct")
    sync_api.expect(page.locator("#submit")).to_have_text("Run reconstruct")
    cloud = page.locator("#in-cloud")
    # the upload to reuse and the run's own clouds to chain are offered
    assert cloud.locator(f'option[value="upload:{upload["id"]}"]').count() == 1
    assert cloud.locator(f'option[value="result:{run_id}:scan.laz"]').count() == 1
    sync_api.expect(page.locator("#uploads tbody tr")).to_have_count(len(uploads))
    assert "cloud.txt" in page.locator(f'#uploads tr[data-upload="{upload["id"]}"]').inner_text()
    cloud.select_option(f"upload:{upload['id']}")
    assert page.locator("#new-cloud").is_hidden()
    # the form shows the schema's defaults, ranges and help
    side = page.locator("#set-leaf_side_m")
    assert side.input_value() == "0.05" and side.get_attribute("max") == "1"
    assert page.locator("#set-leaf_layer").is_checked()
    page.select_option("#set-preset", label="draft")
    page.select_option("#set-method", label="poisson")
    side.fill("0.07")
    page.uncheck("#set-leaf_layer")
    page.locator('details[data-path="prepare"] > summary').click()
    page.fill("#set-prepare-sor_neighbors", "12")
    page.click("#submit")
    sync_api.expect(page.locator("#message")).to_contain_text("accepted", timeout=30_000)
    job = httpx.get(f"{base}/v1/jobs?limit=1", headers=AUTH).json()["jobs"][0]
    assert job["processID"] == "reconstruct"
    assert job["parameters"] == {
        "preset": "draft",
        "method": "poisson",
        "leaf_side_m": 0.07,
        "leaf_layer": False,
        "prepare": {"sor_neighbors": 12},
    }
    assert job["inputs"]["cloud"]["upload"] == upload["id"]
    assert httpx.get(f"{base}/v1/uploads", headers=AUTH).json()["uploads"] == uploads
    return job["jobID"]


def _plot_archive(folder: Path) -> Path:
    """Three saplings in a 5 m plot (as treesim plot generate leaves them), zipped."""
    plot = folder / "myplot"
    plot.mkdir(parents=True)
    trees = [
        PlotTree(tree_id=i + 1, x_m=x, y_m=y, species="sapling", seed=i)
        for i, (x, y) in enumerate([(2.0, 0.0), (-2.0, 1.0), (0.0, -2.5)])
    ]
    write_plot(plot / "plot.toml", Plot(trees, radius_m=5.0, facets=8))
    archive = folder / "saplings.zip"
    with zipfile.ZipFile(archive, "w") as z:
        for f in sorted(plot.iterdir()):
            z.write(f, f"myplot/{f.name}")
    return archive


def _plot_scan_of_an_archive(page, base: str, sync_api, archive: Path) -> None:
    """``plot-scan`` of a plot archive uploaded through the form, its stations given by
    value and its range noise turned on: the job holds these and succeeds."""
    page.select_option("#process", "plot-scan")
    sync_api.expect(page.locator("#submit")).to_have_text("Run plot-scan")
    assert page.locator("#new-plot").get_attribute("accept") == ".zip"
    page.select_option("#in-plot", "new")
    page.set_input_files("#new-plot", str(archive))
    page.select_option("#in-stations", "value")
    page.fill("#value-stations", "[[0, 7], [7, 0]]")
    page.select_option("#set-preset", label="draft")
    assert not page.locator("#set-noise").is_checked()
    page.check("#set-noise")
    page.click("#submit")
    sync_api.expect(page.locator("#message")).to_contain_text("accepted", timeout=30_000)
    job = httpx.get(f"{base}/v1/jobs?limit=1", headers=AUTH).json()["jobs"][0]
    assert job["processID"] == "plot-scan"
    assert job["parameters"] == {"preset": "draft", "noise": True, "stations": [[0, 7], [7, 0]]}
    assert job["inputs"]["plot"]["filename"] == "saplings.zip"
    row = page.locator(f'#jobs tr[data-job="{job["jobID"]}"]')
    sync_api.expect(row).to_have_attribute("data-status", "successful", timeout=120_000)


def _dismiss(page, base: str, sync_api, job_id: str) -> None:
    row = page.locator(f'#jobs tr[data-job="{job_id}"]')
    sync_api.expect(row).to_have_count(1, timeout=10_000)
    page.once("dialog", lambda d: d.accept())
    row.locator("button.dismiss").click()
    sync_api.expect(row).to_have_count(0, timeout=10_000)
    assert httpx.get(f"{base}/v1/jobs/{job_id}", headers=AUTH).json()["status"] == "dismissed"
    page.check("#show-dismissed")
    sync_api.expect(row).to_have_attribute("data-status", "dismissed", timeout=10_000)
    page.uncheck("#show-dismissed")
    sync_api.expect(row).to_have_count(0, timeout=10_000)


def _results_and_3d_view(page, sync_api, run_id: str) -> None:
    row = page.locator(f'#jobs tr[data-job="{run_id}"]')
    row.locator("button.results-toggle").click()
    files = page.locator(f'#jobs tr[data-results-of="{run_id}"] li')
    sync_api.expect(files.first).to_be_visible(timeout=10_000)
    names = {li.split(" ")[0] for li in files.all_inner_texts()}
    assert {"report.html", "scan.laz", "tree.ply", "run.json"} <= names, names
    scan = page.locator(f'#jobs tr[data-results-of="{run_id}"] a[download="scan.laz"]')
    got = page.request.get(scan.get_attribute("href"))  # the session cookie opens downloads
    assert got.status == 200 and got.body()[:4] == b"LASF"
    report_item = files.filter(has_text=re.compile(r"^report\.html"))
    report_item.locator("button.view3d").click()
    sync_api.expect(page.locator("#view")).to_be_visible()
    frame = page.frame_locator("#view-frame")
    sync_api.expect(frame.locator("body")).to_have_attribute("data-viewer", "ready", timeout=60_000)
    sync_api.expect(frame.locator("#viewer")).to_have_attribute(
        "data-drawn", re.compile(r"^[1-9]\d*$"), timeout=60_000
    )
    assert frame.locator("html").get_attribute("data-errors") == "0", frame.locator(
        "#page-errors"
    ).inner_text()


def _open_the_report(page, sync_api, run_id: str) -> None:
    page.locator(f'#jobs tr[data-job="{run_id}"]').get_by_role("link", name="report").click()
    page.wait_for_load_state()
    assert f"/v1/jobs/{run_id}/results/report.html" in page.url
    sync_api.expect(page.locator("body")).to_have_attribute("data-viewer", "ready", timeout=60_000)
    assert page.locator("html").get_attribute("data-errors") == "0"


def test_jobs_page_offers_every_process_and_runs_reuses_dismisses_and_views(serve, tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api", reason="needs playwright (dev extra)")
    exe = chromium()
    base, _ = serve(tmp_path / "data", workers=1, TREESIM_API_TOKEN=TOKEN)
    csp = httpx.get(base + "/", headers={"Accept": "text/html"}).headers["content-security-policy"]
    assert "script-src 'self';" in csp and "unsafe" not in csp and "http" not in csp
    outside: list[str] = []
    errors: list[str] = []
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(
            executable_path=exe,
            args=["--no-sandbox", "--disable-gpu", "--disable-background-networking"],
        )
        try:
            page = browser.new_page()
            _watch(page, base, outside, errors)
            _sign_in(page, base, sync_api)
            options = page.locator("#process option")
            sync_api.expect(options).to_have_count(len(PROCESSES))
            assert [o.get_attribute("value") for o in options.all()] == list(PROCESSES)
            refused = _api_error_is_shown(page, sync_api)
            # the one refusal asked for: its response and the console's line about it
            assert f"422 {refused}" in errors and all("422" in e for e in errors), errors
            errors.clear()
            run_id = _run_uploaded_tree(page, base, sync_api)
            _plot_scan_of_an_archive(page, base, sync_api, _plot_archive(tmp_path / "plot"))
            other = _reconstruct_reusing_the_upload(page, base, sync_api, run_id)
            _dismiss(page, base, sync_api, other)
            _results_and_3d_view(page, sync_api, run_id)
            _open_the_report(page, sync_api, run_id)
        finally:
            browser.close()
    assert outside == [], f"the page loaded outside resources: {outside}"
    assert errors == [], errors
