"""``/docs`` and ``/redoc`` (issue 24): served from the package's own copies of Swagger UI
and ReDoc (provenance in ``service/static/THIRD_PARTY.md``), under a Content-Security-Policy
that allows no other origin; in headless Chromium both render with nothing loaded from
outside and no CSP violation."""

from __future__ import annotations

import base64
import hashlib
import re
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from treesim.service.app import create_app
from treesim.service.settings import Settings

STATIC = Path(__file__).resolve().parents[2] / "service" / "static"


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    app = create_app(
        Settings(data_dir=tmp_path_factory.mktemp("docs") / "data", workers=0, api_token=None)
    )
    with TestClient(app) as c:
        yield c


def _recorded_hashes() -> dict[str, str]:
    """file → SHA-256 as the provenance table records it (written when vendored)."""
    text = (STATIC / "THIRD_PARTY.md").read_text()
    return dict(re.findall(r"\| `([\w.-]+)` \|[^|]*\|[^|]*\| `([0-9a-f]{64})` \|", text))


def test_assets_are_the_recorded_files(client):
    recorded = _recorded_hashes()
    assert set(recorded) == {"swagger-ui-bundle.js", "swagger-ui.css", "redoc.standalone.js"}
    for name, digest in recorded.items():
        r = client.get(f"/static/{name}")
        assert r.status_code == 200
        assert hashlib.sha256(r.content).hexdigest() == digest
        assert r.headers["x-content-type-options"] == "nosniff"
    assert client.get("/static/index.html").status_code == 404
    assert client.get("/static/..%2Fsettings.py").status_code == 404


@pytest.mark.parametrize("path", ["/docs", "/redoc"])
def test_docs_pages_name_no_other_origin_and_carry_a_csp(client, path):
    r = client.get(path)
    assert r.status_code == 200
    page = r.text
    assert "cdn" not in page.lower() and "googleapis" not in page
    srcs = re.findall(r'(?:src|href)="([^"]+)"', page)
    assert srcs and all(s.startswith("/") for s in srcs), srcs
    csp = r.headers["content-security-policy"]
    assert "default-src 'none'" in csp and "http" not in csp
    # each inline script is allowed by its own hash, computed here independently
    for script in re.findall(r"<script>(.*?)</script>", page, flags=re.DOTALL):
        digest = base64.b64encode(hashlib.sha256(script.encode()).digest()).decode()
        assert f"'sha256-{digest}'" in csp


@pytest.mark.slow
@pytest.mark.parametrize("path, selector", [("/docs", ".swagger-ui .info"), ("/redoc", "h1")])
def test_docs_render_offline_in_chromium(serve, tmp_path, path, selector):
    sync_api = pytest.importorskip("playwright.sync_api", reason="needs playwright (dev extra)")
    from tests.report.browser import chromium

    exe = chromium()
    base, _ = serve(tmp_path / "data", workers=0)
    outside: list[str] = []
    errors: list[str] = []
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(
            executable_path=exe,
            args=["--no-sandbox", "--disable-gpu", "--disable-background-networking"],
        )
        try:
            page = browser.new_page()
            # what reached another origin (ReDoc asks for Redocly's logo on cdn.redoc.ly: the
            # CSP refuses it, so the request fails and nothing leaves; blob: is ReDoc's worker)
            page.on(
                "requestfinished",
                lambda r: (
                    None if r.url.startswith((base, "blob:", "data:")) else outside.append(r.url)
                ),
            )
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.goto(base + path)
            sync_api.expect(page.locator(selector).first).to_contain_text("treesim", timeout=30_000)
        finally:
            browser.close()
    assert not outside, outside
    # the only refusal the CSP may log is of that logo
    refused = [e for e in errors if "Content Security Policy" in e or "Refused" in e]
    assert all("cdn.redoc.ly" in e for e in refused), refused
