"""Open a report page in headless Chromium (Playwright) and wait for its 3D view's drawing."""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

import pytest


def chromium() -> str:
    """The Chromium to drive; skips the test when there is none."""
    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        path = shutil.which(name)
        if path:
            return path
    if os.path.exists("/usr/bin/chromium"):
        return "/usr/bin/chromium"
    pytest.skip("chromium is not installed (apt-get install chromium)")


def open_page(path: Path, *, screenshot: Path | None = None) -> dict[str, Any]:
    """Load ``path`` from disk, wait until the 3D view has drawn its first frame (its
    ``data-drawn`` attribute, set by the drawing itself, however long a cold start
    takes), and return what the page shows.

    Returns
    -------
    dict
        ``errors`` (``<html data-errors>``: script errors, failed resources,
        ``console.error`` calls), ``console`` (every console message), ``outside``
        (requests that left the file), ``drawn`` (points the view drew), ``viewer``
        (``<body data-viewer>``), ``images`` (inline PNGs) and ``images_ok`` (all loaded
        with a size).
    """
    sync_api = pytest.importorskip("playwright.sync_api", reason="needs playwright (dev extra)")
    exe = chromium()
    console: list[str] = []
    outside: list[str] = []
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(
            executable_path=exe,
            args=["--no-sandbox", "--disable-gpu", "--disable-background-networking"],
        )
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 2000})
            page.on("console", lambda m: console.append(f"{m.type}: {m.text}"))
            page.on("pageerror", lambda e: console.append(f"pageerror: {e}"))
            page.on(
                "request",
                lambda r: None if r.url.startswith(("file:", "data:")) else outside.append(r.url),
            )
            page.goto(path.resolve().as_uri(), wait_until="load")
            page.wait_for_function(
                "() => Number((document.getElementById('viewer') || document.body)"
                ".getAttribute('data-drawn')) > 0",
                timeout=90_000,
            )
            out = {
                "errors": page.get_attribute("html", "data-errors"),
                "viewer": page.get_attribute("body", "data-viewer"),
                "drawn": int(page.get_attribute("#viewer", "data-drawn") or 0),
                "images": page.locator('img[src^="data:image/png;base64,"]').count(),
                "images_ok": page.evaluate(
                    "Array.from(document.images).every(i => i.complete && i.naturalWidth > 0)"
                ),
                "console": console,
                "outside": outside,
            }
            if screenshot is not None:
                page.screenshot(path=str(screenshot))
            return out
        finally:
            browser.close()
