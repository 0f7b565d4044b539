"""The report's SVG figures (pospp.report.svg): what is drawn is where the axes say it is.

Each check reads the SVG back as XML (the standard library's parser) and recovers the data
from the drawing through the tick labels alone: a tick label's text is a data value and its
position a pixel, so the line's pixels, mapped through the ticks, must give back the data
the figure was given (linear and log axes). Also: the min-max decimation keeps every
column's extremes (brute force with numpy), and every figure of a synthetic report is a
well-formed SVG.
"""

from __future__ import annotations

import base64
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from pospp.report import _svg_draw, figures, svg
from pospp.report.html import render_report

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_report import synthetic_tables  # noqa: E402

NS = "{http://www.w3.org/2000/svg}"


def _parse(fig: svg.Figure) -> ET.Element:
    return ET.fromstring(fig.to_svg())


def _label_value(el: ET.Element) -> float:
    text = "".join(el.itertext()).replace("\u2212", "-")
    if el.find(f"{NS}tspan") is not None:  # "10" with the exponent as a superscript
        return 10.0 ** float(text[2:])
    return float(text)


def _ticks(root: ET.Element, axis: str) -> tuple[np.ndarray, np.ndarray]:
    """(pixel, value) of the numeric tick labels of one axis: x labels hang below the frame
    (dominant-baseline hanging, centred), y labels end left of it (anchor end, middle)."""
    px, val = [], []
    for el in root.iter(f"{NS}text"):
        a = el.attrib
        if axis == "x" and a.get("dominant-baseline") == "hanging" and \
                a.get("text-anchor") == "middle":
            pos = float(a["x"])
        elif axis == "y" and a.get("dominant-baseline") == "middle" and \
                a.get("text-anchor") == "end":
            pos = float(a["y"])
        else:
            continue
        try:
            v = _label_value(el)
        except ValueError:  # an axis label, not a number
            continue
        px.append(pos)
        val.append(v)
    return np.array(px), np.array(val)


def _polyline(root: ET.Element, i: int = 0) -> np.ndarray:
    lines = list(root.iter(f"{NS}polyline"))
    return np.array([[float(v) for v in p.split(",")] for p in lines[i].attrib["points"].split()])


def test_linear_line_maps_back_through_the_tick_labels() -> None:
    x = np.linspace(-3.0, 17.0, 201)
    y = 0.37 * x - 2.0
    fig, ax = svg.subplots(figsize=(6, 4))
    ax.plot(x, y)
    ax.grid(alpha=0.3)
    root = _parse(fig)
    tx, vx = _ticks(root, "x")
    ty, vy = _ticks(root, "y")
    assert len(vx) >= 3 and len(vy) >= 3
    # ticks are equally spaced values at equally spaced pixels (a linear axis)
    ax_x, bx = np.polyfit(vx, tx, 1)
    ax_y, by = np.polyfit(vy, ty, 1)
    assert np.max(np.abs(np.polyval([ax_x, bx], vx) - tx)) < 0.06
    assert ax_y < 0  # y grows upwards
    pts = _polyline(root)
    xd, yd = (pts[:, 0] - bx) / ax_x, (pts[:, 1] - by) / ax_y
    # pixels carry 0.1 px: data back to 0.1 px / scale
    assert np.max(np.abs(yd - (0.37 * xd - 2.0))) < 0.1 / abs(ax_y) + 0.1 / abs(ax_x)
    assert xd.min() == pytest.approx(-3.0, abs=0.1 / ax_x) and \
        xd.max() == pytest.approx(17.0, abs=0.1 / ax_x)


def test_log_axis_draws_a_power_law_as_a_straight_line() -> None:
    t = np.linspace(0.0, 100.0, 101)
    s = 10.0 ** (-2.0 + 0.04 * t)  # 1e-2 .. 1e2
    fig, ax = svg.subplots(figsize=(6, 4))
    ax.semilogy(t, s, label="s")
    ax.legend()
    root = _parse(fig)
    ty, vy = _ticks(root, "y")
    assert set(np.round(np.log10(vy))) >= {-2.0, -1.0, 0.0, 1.0, 2.0}
    a, b = np.polyfit(np.log10(vy), ty, 1)  # decades equally spaced in pixels
    assert np.max(np.abs(np.polyval([a, b], np.log10(vy)) - ty)) < 0.06
    tx, vx = _ticks(root, "x")
    ax_x, bx = np.polyfit(vx, tx, 1)
    pts = _polyline(root)
    td, ld = (pts[:, 0] - bx) / ax_x, (pts[:, 1] - b) / a
    assert np.max(np.abs(ld - (-2.0 + 0.04 * td))) < 0.01


def test_decimation_keeps_every_column_extreme() -> None:
    rng = np.random.default_rng(3)
    n = 50_000
    px = np.linspace(10.0, 710.0, n)
    py = np.cumsum(rng.normal(size=n))
    keep = _svg_draw._decimate(px, py)
    assert len(keep) < n / 10
    col = np.floor(px)
    for c in np.unique(col)[::37]:  # brute force over a sample of columns
        m = col == c
        kept = keep[col[keep] == c]
        assert py[kept].min() == py[m].min() and py[kept].max() == py[m].max()
        assert kept.min() == np.flatnonzero(m).min() and kept.max() == np.flatnonzero(m).max()


def test_nan_breaks_the_line_and_shared_axes_agree() -> None:
    fig, axes = svg.subplots(2, 1, figsize=(6, 5), sharex=True)
    y = np.r_[np.arange(10.0), np.nan, np.arange(10.0)]
    axes[0].plot(np.arange(21.0), y)
    axes[1].plot(np.arange(5.0), np.ones(5))
    root = _parse(fig)
    assert len(list(root.iter(f"{NS}polyline"))) == 3  # two runs on top, one below
    tx, vx = _ticks(root, "x")  # only the bottom axes labels x (shared)
    assert len(vx) == len(set(vx))
    bottom_line = _polyline(root, 2)
    a, b = np.polyfit(vx, tx, 1)
    assert (bottom_line[:, 0] - b) / a == pytest.approx(np.arange(5.0), abs=0.01)


def test_report_figures_are_svg_documents() -> None:
    page = render_report(synthetic_tables(n_legs=12))
    blobs = re.findall(r'src="data:image/svg\+xml;base64,([^"]+)"', page)
    assert len(blobs) >= 6 and "image/png" not in page
    for b in blobs:
        root = ET.fromstring(base64.b64decode(b))
        assert root.tag == f"{NS}svg" and len(list(root.iter(f"{NS}text"))) > 5


def test_both_backends_draw_the_same_series() -> None:
    """The same figure function through matplotlib and SVG: the same line data."""
    tables = synthetic_tables(n_legs=3)
    mfig = figures.leg_error_curves(tables["leg_errors"], "velocity")
    sfig = figures.leg_error_curves(tables["leg_errors"], "velocity", backend="svg")
    m_lines = [ln.get_ydata() for ax in mfig.axes for ln in ax.lines]
    s_lines = [a["y"] for ax in sfig.axes for a in ax._artists if a["kind"] == "line"]
    assert len(m_lines) == len(s_lines) == 12
    for m, s in zip(m_lines, s_lines, strict=True):
        assert np.array_equal(np.asarray(m, dtype=float), s)
    figures.pyplot().close(mfig)
