"""A report page as a browser shows it: headless Chromium (Debian's ``chromium``, which ``make``
installs) draws the page into a screenshot and reports, from the loaded page, whether each
picture was decoded. ``TISSUE_NO_BROWSER=1`` turns the check off; without it a machine that
lacks Chromium fails the check, naming what to install."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest

TIMEOUT_S = 90
WINDOW = "1200,2000"
MIN_COLOURS = 16        # a blank or unstyled page has a handful; text and tables have many
NAMES = ("chromium", "chromium-browser")
# set on <body> after the load event: each <img>'s natural width, 0 where it was not decoded
_PROBE = ("<script>window.addEventListener('load',function(){document.body.setAttribute("
          "'data-image-widths',Array.from(document.images).map(function(i){return i.complete"
          "&&i.naturalWidth>0?i.naturalWidth:0}).join(' '))});</script>")
_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", f"--window-size={WINDOW}",
          "--hide-scrollbars")


class BrowserError(AssertionError):
    pass


def browser() -> str | None:
    """The Chromium executable, or None when there is none."""
    return next((p for p in map(shutil.which, NAMES) if p), None)


def browser_disabled() -> bool:
    return os.environ.get("TISSUE_NO_BROWSER", "") not in ("", "0")


def require_browser() -> str:
    """The Chromium executable; skips with TISSUE_NO_BROWSER=1, and fails naming what to
    install when there is none."""
    if browser_disabled():
        pytest.skip("TISSUE_NO_BROWSER is set: the pages are not drawn in a browser")
    exe = browser()
    if exe is None:
        pytest.fail("chromium is not installed, so the report pages cannot be drawn in a "
                    "headless browser: `make test` installs it (Makefile APT_PKGS), or run "
                    "`apt-get install --no-install-recommends chromium`; TISSUE_NO_BROWSER=1 "
                    "skips this check", pytrace=False)
    return exe


def _run(exe: str, args: list, profile: str) -> subprocess.CompletedProcess:
    cmd = [exe, *_FLAGS, f"--user-data-dir={profile}", *args]
    try:
        return subprocess.run(cmd, capture_output=True, text=True, timeout=TIMEOUT_S,
                              check=False)
    except subprocess.TimeoutExpired as exc:
        raise BrowserError(f"{' '.join(cmd)}: no answer within {TIMEOUT_S} s") from exc


def colours(png) -> int:
    """The number of distinct RGB colours of a PNG."""
    from PIL import Image

    with Image.open(png) as im:
        a = np.asarray(im.convert("RGB"), np.uint32)
    return len(np.unique((a[..., 0] << 16) | (a[..., 1] << 8) | a[..., 2]))


def render_page(page, exe: str, shot) -> dict:
    """Draw ``page`` (an HTML file) with the browser ``exe`` into the PNG ``shot`` and load it
    once more with a probe of its pictures. Raises BrowserError naming what is wrong: the
    browser failed or hung, no or a near-blank screenshot, an <img> that did not load. Returns
    {"colours": distinct colours of the screenshot, "image_widths": natural width per <img>}."""
    page, shot = Path(page).resolve(), Path(shot)
    with tempfile.TemporaryDirectory() as profile:
        run = _run(exe, [f"--screenshot={shot}", page.as_uri()], profile)
        if run.returncode != 0 or not shot.is_file():
            raise BrowserError(f"{page}: the browser exited {run.returncode} without a "
                               f"screenshot: {run.stderr.strip()[-500:]}")
        n = colours(shot)
        if n < MIN_COLOURS:
            raise BrowserError(f"{page}: the screenshot is near blank ({n} colours)")
        # a copy beside the page (its pictures are relative links) with the probe added
        probe = page.with_name(f".browser_check_{page.name}")
        try:
            probe.write_text(page.read_text(encoding="utf-8").replace(
                "</body>", _PROBE + "</body>"), encoding="utf-8")
            run = _run(exe, ["--dump-dom", probe.as_uri()], profile)
        finally:
            probe.unlink(missing_ok=True)
    if run.returncode != 0:
        raise BrowserError(f"{page}: --dump-dom exited {run.returncode}: "
                           f"{run.stderr.strip()[-500:]}")
    imgs = re.findall(r"<img\b[^>]*>", run.stdout)
    m = re.search(r"data-image-widths=\"([^\"]*)\"", run.stdout)
    if m is None:
        raise BrowserError(f"{page}: the page's load event never came")
    widths = [int(w) for w in m.group(1).split()]
    if len(widths) != len(imgs):
        raise BrowserError(f"{page}: {len(imgs)} <img> in the DOM, {len(widths)} probed")
    broken = [re.search(r"src=\"([^\"]*)\"", t).group(1) for t, w in zip(imgs, widths) if not w]
    if broken:
        raise BrowserError(f"{page}: pictures the browser could not load: {broken}")
    return {"colours": n, "image_widths": widths}
