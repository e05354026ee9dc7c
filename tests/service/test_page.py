"""The jobs page ``GET /`` in headless Chromium (driven by Playwright against the real
server): with a token set, the page says so; given the token it lists jobs, uploads the
bundled tree, starts a draft run, shows its progress and, once it succeeds, a report link
that opens the report. The page loads nothing from outside and logs no error."""

from __future__ import annotations

import pytest

from tests.report.browser import chromium

from .conftest import BUNDLED_CLOUD

pytestmark = pytest.mark.slow


def test_jobs_page_uploads_runs_and_links_the_report(serve, tmp_path):
    sync_api = pytest.importorskip("playwright.sync_api", reason="needs playwright (dev extra)")
    exe = chromium()
    base, _ = serve(tmp_path / "data", workers=1, TREESIM_API_TOKEN="page-token")
    outside: list[str] = []
    errors: list[str] = []
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(
            executable_path=exe,
            args=["--no-sandbox", "--disable-gpu", "--disable-background-networking"],
        )
        try:
            page = browser.new_page()
            page.on("request", lambda r: None if r.url.startswith(base) else outside.append(r.url))
            page.on("pageerror", lambda e: errors.append(str(e)))
            # the page's polls before the token is given are 401s by design: not errors
            page.on(
                "console",
                lambda m: (
                    errors.append(m.text)
                    if m.type == "error" and "status of 401" not in m.text
                    else None
                ),
            )
            page.on(
                "response",
                lambda r: (
                    errors.append(f"{r.status} {r.url}")
                    if r.status >= 400 and r.status != 401
                    else None
                ),
            )
            page.goto(base + "/")
            # without the token the API answers 401 and the page says what is missing
            sync_api.expect(page.locator("#token-state")).to_contain_text("token", timeout=10_000)
            page.fill("#token", "page-token")
            page.click("#token-save")
            sync_api.expect(page.locator("#token-state")).to_have_text("", timeout=10_000)
            sync_api.expect(page.locator("#preset option")).to_have_count(3)
            page.select_option("#preset", "draft")
            page.set_input_files("#file", str(BUNDLED_CLOUD))
            page.click("#run")
            sync_api.expect(page.locator("#message")).to_contain_text("draft", timeout=30_000)
            row = page.locator("#jobs tbody tr").first
            sync_api.expect(row).to_have_attribute("data-status", "successful", timeout=240_000)
            assert row.locator("progress").get_attribute("value") == "100"
            assert "cloud.txt" in row.inner_text()
            report = row.get_by_role("link", name="report")
            report.click()
            page.wait_for_load_state()
            assert "/results/report.html" in page.url
            assert page.locator("html").count() == 1 and page.title()
            # a comparison's report, with its 3D view, runs under the results' CSP
            page.goto(page.url.replace("/report.html", "/vs_mesh/report.html"))
            body = page.locator("body")
            sync_api.expect(body).to_have_attribute("data-viewer", "ready", timeout=30_000)
            assert page.locator("html").get_attribute("data-errors") == "0"
        finally:
            browser.close()
    assert outside == [], f"the page loaded outside resources: {outside}"
    assert errors == [], errors
