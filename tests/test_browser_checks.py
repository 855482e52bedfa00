"""The browser check of the report pages (browser_checks) finds what is wrong: no Chromium
(a failure naming what to install, a skip with TISSUE_NO_BROWSER=1), a blank page, a picture
that does not load; a page with a picture passes."""
import pytest
from browser_checks import BrowserError, render_page, require_browser


def test_the_browser_check_finds_a_blank_page_and_a_missing_picture(tmp_path, monkeypatch):
    import browser_checks

    monkeypatch.setattr(browser_checks, "browser", lambda: None)
    monkeypatch.setenv("TISSUE_NO_BROWSER", "0")
    with pytest.raises(pytest.fail.Exception, match="chromium is not installed"):
        require_browser()
    monkeypatch.setenv("TISSUE_NO_BROWSER", "1")
    with pytest.raises(pytest.skip.Exception):
        require_browser()
    monkeypatch.undo()
    exe = require_browser()
    doc = "<!DOCTYPE html><html><head><title>t</title></head><body>{}</body></html>"
    (tmp_path / "blank.html").write_text(doc.format(""))
    with pytest.raises(BrowserError, match="near blank"):
        render_page(tmp_path / "blank.html", exe, tmp_path / "blank.png")
    table = "<h1>A heading</h1><table border=1><tr><th>push (mm)</th></tr><tr><td>5</td></tr>" \
            "</table>"
    (tmp_path / "missing.html").write_text(doc.format(table + "<img src='gone.png'>"))
    with pytest.raises(BrowserError, match=r"could not load: \['gone.png'\]"):
        render_page(tmp_path / "missing.html", exe, tmp_path / "missing.png")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(3, 2))
    ax.plot([0, 1], [1, 0])
    fig.savefig(tmp_path / "line.png", dpi=100)
    plt.close(fig)
    (tmp_path / "good.html").write_text(doc.format(table + "<img src='line.png'>"))
    assert render_page(tmp_path / "good.html", exe, tmp_path / "good.png")["image_widths"] == [300]
