"""Headless Chromium for the browser tests and the README's screenshot: Debian's chromium
(/usr/bin/chromium, installed by .ci/run) driven by Playwright, with a fresh profile and nothing
that reaches the network. Never `playwright install`: no browser is downloaded.

    .venv/bin/python tests/browser.py docs/pipeline-view.png

writes the screenshot README shows: `retrosim loop examples/texture-loop.s` on one CPU of each
family, drawn by the page `--html` writes.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from pathlib import Path

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]
SCREENSHOT_CPUS = "pentium-mmx-233,pentium2-233,k6-2-300"


def missing_reason() -> str | None:
    """Why the browser cannot run here (None: it can)."""
    if not Path(CHROMIUM).exists():
        return f"{CHROMIUM} is missing (Debian: apt-get install chromium; .ci/run installs it)"
    try:
        import playwright  # noqa: F401
    except ImportError:
        return "the playwright package is missing (pip install -e '.[test]')"
    return None


def require() -> None:
    """Skip the calling test when the browser cannot run here; fail it under CI=true (CI installs
    chromium: a browser test that silently skipped there would prove nothing)."""
    import pytest

    why = missing_reason()
    if why:
        if os.environ.get("CI") == "true":
            pytest.fail(f"browser tests cannot run in CI: {why}")
        pytest.skip(why)


@contextlib.contextmanager
def browser_context(width: int = 1600, height: int = 1000):
    """A Playwright browser context on Debian's chromium with a fresh user-data directory."""
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory(prefix="retrosim-chromium-") as profile, sync_playwright() as p:
        context = p.chromium.launch_persistent_context(
            profile, executable_path=CHROMIUM, headless=True, args=ARGS,
            viewport={"width": width, "height": height})
        try:
            yield context
        finally:
            context.close()


def screenshot(out: Path) -> None:
    from click.testing import CliRunner

    from sim.cli import main

    os.chdir(Path(__file__).resolve().parents[1])  # the page names the body as README's command does
    with tempfile.TemporaryDirectory() as tmp:
        page_file = Path(tmp) / "pipeline.html"
        r = CliRunner().invoke(main, ["loop", "examples/texture-loop.s", "--cpu", SCREENSHOT_CPUS,
                                      "--html", str(page_file), "--brief"])
        if r.exit_code != 0:
            raise SystemExit(r.output)
        with browser_context(1280, 1000) as context:
            page = context.new_page()
            page.goto(page_file.as_uri())
            page.wait_for_selector("body[data-state=ready]")
            # the Pentium MMX's store, marked with the write-buffer wait it pays
            page.hover(".cpu[data-cpu='pentium-mmx-233'] .row[data-stall] >> nth=0")
            page.screenshot(path=str(out))


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit("usage: python tests/browser.py OUT.png")
    if (why := missing_reason()):
        raise SystemExit(why)
    sys.path.insert(0, os.fspath(Path(__file__).resolve().parents[1]))
    screenshot(Path(sys.argv[1]))
    print(f"wrote {sys.argv[1]}")
