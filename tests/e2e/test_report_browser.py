"""report.html in a real headless browser (Debian's chromium): the headline values are visible
text and nothing widens the page (issue 15 item 2).

The page is rendered from synthetic run tables with 30 legs (tests/unit/test_report.py), a
script added to the page records what the browser laid out (the answer box's innerText,
which holds only rendered text, and the page's scroll width against the window's) as
attributes that ``--dump-dom`` prints. Skips with a message when chromium is absent
(.ci/run installs it).
"""

from __future__ import annotations

import html
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "unit"))
from test_report import synthetic_tables  # noqa: E402

from pospp.report.html import render_report  # noqa: E402

_PROBE = """<script>
window.addEventListener('load', () => {
  const doc = document.documentElement;
  const wide = [...document.querySelectorAll('body *')]
    .filter(e => e.getBoundingClientRect().right > window.innerWidth + 1
                 && !e.closest('.tw'))
    .map(e => e.tagName + '.' + e.className).slice(0, 5);
  document.body.setAttribute('data-scroll-width', doc.scrollWidth);
  document.body.setAttribute('data-window-width', window.innerWidth);
  document.body.setAttribute('data-wide', wide.join(' '));
  document.body.setAttribute('data-answer', document.getElementById('answer').innerText);
});
</script></body>"""


def _chromium() -> str:
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("chromium not installed (apt-get install -y chromium; .ci/run does it)")
    return exe


def _browser(exe: str, tmp: Path, page: Path, *extra: str) -> str:
    cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
           "--disable-component-update", "--disable-sync", "--no-first-run",
           "--hide-scrollbars", f"--user-data-dir={tmp / 'profile'}", *extra, page.as_uri()]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=True)
    return out.stdout


@pytest.fixture(scope="module")
def report_text() -> str:
    return render_report(synthetic_tables(n_legs=30))


def _layout(exe: str, tmp: Path, text: str, width: int) -> dict[str, str]:
    page = tmp / "report.html"
    page.write_text(text.replace("</body>", _PROBE), encoding="utf-8")
    dom = _browser(exe, tmp, page, f"--window-size={width},900", "--dump-dom")
    body = re.search(r"<body([^>]*)>", dom)
    assert body, dom[:500]
    return {k: html.unescape(v) for k, v in re.findall(r'(data-[\w-]+)="([^"]*)"',
                                                       body.group(1))}


@pytest.mark.parametrize("width", [900, 1400])
def test_headline_is_visible_and_nothing_overflows(tmp_path, report_text, width) -> None:
    attrs = _layout(_chromium(), tmp_path, report_text, width)
    assert int(attrs["data-window-width"]) == width
    assert int(attrs["data-scroll-width"]) <= width, attrs["data-wide"]
    assert attrs["data-wide"] == ""
    answer = attrs["data-answer"]
    for text in ("ok", "+0.94 \u00b1 0.29 deg/h", "-0.55 \u00b1 0.29 deg/h", "not observable",
                 "improvement, in-sample", "2.27 \u2192 0.3 m/s", "improvement, held out",
                 "0.39 m/s"):
        assert text in answer, f"{text!r} not visible in the answer box: {answer!r}"
    assert "313" not in answer  # the unobservable phi_z is flagged, not printed


def test_the_probe_sees_an_overflow(tmp_path, report_text) -> None:
    """Control: the same check on a page with one 3000 px wide block reports it."""
    wide = report_text.replace("<h1>", "<div style='width:3000px'>wide</div><h1>", 1)
    attrs = _layout(_chromium(), tmp_path, wide, 900)
    assert int(attrs["data-scroll-width"]) >= 3000 and "DIV" in attrs["data-wide"]


def test_screenshot_is_drawn(tmp_path, report_text) -> None:
    exe = _chromium()
    page = tmp_path / "report.html"
    page.write_text(report_text, encoding="utf-8")
    shot = tmp_path / "shot.png"
    _browser(exe, tmp_path, page, "--window-size=1000,1400", f"--screenshot={shot}")
    from PIL import Image

    with Image.open(shot) as im:
        assert im.size == (1000, 1400)
        colours = im.convert("RGB").resize((50, 70)).getcolors(maxcolors=4096)
    assert colours is None or len(colours) > 20, "blank screenshot"
