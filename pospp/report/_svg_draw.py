"""SVG drawing of :mod:`pospp.report.svg`'s figures: ticks, lines, bands, bars, legends.

Private module: :class:`pospp.report.svg.Figure` records what is plotted, the functions here
write it as SVG elements (text). Sizes in pixels at :data:`DPI`; points at 72 per inch.
"""

from __future__ import annotations

import html
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    from pospp.report.svg import Axes

Mapper = Callable[[ArrayLike], np.ndarray]
"""Data -> pixel map of one axis (:func:`_mappers`)."""

DPI = 80.0
"""Pixels per inch of the drawing (the PNG figures were saved at 80 dpi)."""
PX_PER_PT = DPI / 72.0
"""Pixels per typographic point (1 pt = 1/72 inch) at :data:`DPI`."""
_FONT_PT = 10.0
_DASHES = {"-": None, "solid": None, "--": (3.7, 1.6), "dashed": (3.7, 1.6),
           ":": (1.0, 1.65), "dotted": (1.0, 1.65), "-.": (6.4, 1.6, 1.0, 1.6),
           "dashdot": (6.4, 1.6, 1.0, 1.6)}


def _f(v: float) -> str:
    """A pixel coordinate as short text (0.1 px)."""
    return f"{v:.1f}"


def svg_text(x: float, y: float, s: str, size_pt: float, *, anchor: str = "middle",
             baseline: str = "auto", color: str = "#000000", weight: str | None = None,
             rotate: float = 0.0) -> str:
    """An SVG ``<text>`` element at pixel (x, y), ``size_pt`` points, rotated ``rotate``
    degrees about (x, y); ``s`` escaped, a ``10^{k}`` tick label as a superscript."""
    tr = f' transform="rotate({rotate:g} {_f(x)} {_f(y)})"' if rotate else ""
    wt = f' font-weight="{weight}"' if weight else ""
    fill = "" if color == "#000000" else f' fill="{color}"'
    return (f'<text x="{_f(x)}" y="{_f(y)}" font-size="{size_pt * PX_PER_PT:.1f}" '
            f'text-anchor="{anchor}" dominant-baseline="{baseline}"{fill}{wt}{tr}>'
            f"{_markup(s)}</text>")


def _markup(s: str) -> str:
    """Escaped text; ``10^{k}`` (log tick labels) as a superscript."""
    if s.startswith("10^{") and s.endswith("}"):
        return (f'10<tspan dy="-0.45em" font-size="75%">{html.escape(s[4:-1])}</tspan>'
                '<tspan dy="0.45em"></tspan>')
    return html.escape(s)


def _text_width_px(s: str, size_pt: float) -> float:
    """Approximate width of a text line (0.6 em per character)."""
    if s.startswith("10^{"):
        s = s[4:-1] + "10"
    return 0.6 * size_pt * PX_PER_PT * len(s)


def _nice_ticks(lo: float, hi: float, target: int) -> np.ndarray:
    """Ticks at multiples of 1, 2, 2.5 or 5 x 10^k inside [lo, hi], about ``target``."""
    span = hi - lo
    if not np.isfinite(span) or span <= 0:
        return np.array([lo])
    raw = span / max(1, target)
    mag = 10.0 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1.0, 2.0, 2.5, 5.0, 10.0) if m * mag >= raw * (1 - 1e-9))
    k0, k1 = math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9)
    return np.arange(k0, k1 + 1) * step


def _linear_labels(ticks: np.ndarray) -> list[str]:
    if len(ticks) < 2:
        return [f"{v:g}" for v in ticks]
    step = float(np.min(np.diff(ticks)))
    big = float(np.max(np.abs(ticks)))
    if big >= 1e6 or (big > 0 and step < 1e-4):
        return [f"{v:.3g}" for v in ticks]
    dec = max(0, -math.floor(math.log10(step) + 1e-9))
    if abs(step / 10.0 ** math.floor(math.log10(step) + 1e-9) - 2.5) < 1e-6:
        dec += 1
    out = []
    for v in ticks:
        s = f"{v:.{dec}f}"
        out.append("0" if float(s) == 0 else s.replace("-", "\u2212"))
    return out


def _dash(ls: str, lw_px: float) -> str:
    d = _DASHES.get(ls)
    if d is None:
        return ""
    return f' stroke-dasharray="{",".join(f"{v * lw_px:.1f}" for v in d)}"'


def _paint(c: tuple[str, float], attr: str) -> str:
    col, alpha = c
    op = f' {attr}-opacity="{alpha:.3g}"' if alpha < 1.0 else ""
    return f'{attr}="{col}"{op}'


def _decimate(px: np.ndarray, py: np.ndarray, res_px: float = 1.0) -> np.ndarray:
    """Indices of the points that draw the same line at ``res_px`` resolution: where x is
    monotonic, each ``res_px`` wide column keeps its first, lowest, highest and last point
    (min-max decimation: every peak stays); otherwise every point."""
    col = np.floor(px / res_px)
    steps = np.diff(col)
    if len(px) < 8 or not (np.all(steps >= 0) or np.all(steps <= 0)):
        return np.arange(len(px))
    starts = np.flatnonzero(np.r_[True, steps != 0])
    ends = np.r_[starts[1:], len(px)] - 1
    # sorted by column in the points' order, then by y: a column's first is its lowest
    order = np.lexsort((py, col if steps.sum() >= 0 else -col))
    return np.unique(np.r_[starts, ends, order[starts], order[ends]])


def _points(px: np.ndarray, py: np.ndarray) -> str:
    xy = np.column_stack([px, py]).ravel()
    return ("%.1f,%.1f " * len(px) % tuple(xy.tolist())).rstrip()


def _polyline_runs(px: np.ndarray, py: np.ndarray) -> list[str]:
    """Point lists of the finite runs (a non-finite value breaks the line, as matplotlib),
    min-max decimated to half a pixel (:func:`_decimate`)."""
    ok = np.isfinite(px) & np.isfinite(py)
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return []
    cuts = np.flatnonzero(np.diff(idx) > 1) + 1
    runs = []
    for seg in np.split(idx, cuts):
        x, y = px[seg], py[seg]
        keep = _decimate(x, y)
        runs.append(_points(x[keep], y[keep]))
    return runs


def _marker(kind: str, x: float, y: float, ms_pt: float, fill: str) -> str:
    r = ms_pt * PX_PER_PT / 2
    if kind == "s":
        return (f'<rect x="{_f(x - r)}" y="{_f(y - r)}" width="{_f(2 * r)}" '
                f'height="{_f(2 * r)}" fill="{fill}"/>')
    if kind == ".":
        r /= 2
    return f'<circle cx="{_f(x)}" cy="{_f(y)}" r="{r:.1f}" fill="{fill}"/>'


def _mappers(box: tuple[float, float, float, float],
             lims: tuple[tuple[float, float], tuple[float, float]], log: bool
             ) -> tuple[Mapper, Mapper]:
    """Data -> pixel maps of one axes (module docstring of pospp.report.svg): x linear; y
    linear or log10, non-positive values NaN on a log axis; y grows upwards."""
    x0, y0, w, h = box
    (xlo, xhi), (ylo, yhi) = lims
    tlo, thi = (math.log10(ylo), math.log10(yhi)) if log else (ylo, yhi)

    def fx(v: ArrayLike) -> np.ndarray:
        return x0 + (np.asarray(v, dtype=float) - xlo) / (xhi - xlo) * w

    def fy(v_in: ArrayLike) -> np.ndarray:
        v = np.asarray(v_in, dtype=float)
        if log:
            with np.errstate(divide="ignore", invalid="ignore"):
                v = np.where(v > 0, np.log10(np.where(v > 0, v, 1.0)), np.nan)
        return y0 + h - (v - tlo) / (thi - tlo) * h

    return fx, fy


def _ticks(ax: Axes, box: tuple[float, float, float, float],
           lims: tuple[tuple[float, float], tuple[float, float]]) -> dict[str, Any]:
    """Major x and y ticks with their labels, and the log axis's minor ticks."""
    _, _, w, h = box
    (xlo, xhi), (ylo, yhi) = lims
    if ax._xticks is not None:
        xt = ax._xticks["ticks"]
        xlab = ax._xticks["labels"] or _linear_labels(xt)
        xpt, xrot = ax._xticks["pt"], ax._xticks["rotation"]
        inside = (xt >= xlo - 1e-9 * abs(xhi - xlo)) & (xt <= xhi + 1e-9 * abs(xhi - xlo))
        xt, xlab = xt[inside], [s for s, k in zip(xlab, inside, strict=True) if k]
    else:
        xt = _nice_ticks(xlo, xhi, int(np.clip(w / 50, 3, 9)))
        xlab, xpt, xrot = _linear_labels(xt), _FONT_PT, 0.0
    if ax.yscale == "log":
        yt, ylab, ymin = _log_ticks(ylo, yhi)
    else:
        yt = _nice_ticks(ylo, yhi, int(np.clip(h / 32, 3, 8)))
        ylab, ymin = _linear_labels(yt), np.array([])
    return {"xt": xt, "xlab": xlab, "xpt": xpt, "xrot": xrot, "yt": yt, "ylab": ylab,
            "ymin": ymin}


def _grid_lines(grid: dict[str, Any], box: tuple[float, float, float, float], px: Any,
                py: Any, pminor: Any) -> list[str]:
    x0, y0, w, h = box
    g = [f'<g stroke="#b0b0b0" stroke-width="{0.8 * PX_PER_PT:.2f}" '
         f'stroke-opacity="{grid["alpha"]:.3g}">']
    g.extend(f'<line x1="{_f(v)}" y1="{_f(y0)}" x2="{_f(v)}" y2="{_f(y0 + h)}"/>' for v in px)
    g.extend(f'<line x1="{_f(x0)}" y1="{_f(v)}" x2="{_f(x0 + w)}" y2="{_f(v)}"/>' for v in py)
    if grid["which"] == "both":
        g.extend(f'<line x1="{_f(x0)}" y1="{_f(v)}" x2="{_f(x0 + w)}" y2="{_f(v)}" '
                 'stroke-width="0.5"/>' for v in pminor)
    g.append("</g>")
    return g


def _frame_and_ticks(box: tuple[float, float, float, float], px: Any, py: Any,
                     pminor: Any) -> list[str]:
    x0, y0, w, h = box
    tl = 3.5 * PX_PER_PT
    out = [f'<rect x="{_f(x0)}" y="{_f(y0)}" width="{_f(w)}" height="{_f(h)}" '
           f'fill="none" stroke="#000000" stroke-width="{0.8 * PX_PER_PT:.2f}"/>',
           f'<g stroke="#000000" stroke-width="{0.8 * PX_PER_PT:.2f}">']
    out.extend(f'<line x1="{_f(v)}" y1="{_f(y0 + h)}" x2="{_f(v)}" y2="{_f(y0 + h + tl)}"/>'
               for v in px)
    out.extend(f'<line x1="{_f(x0 - tl)}" y1="{_f(v)}" x2="{_f(x0)}" y2="{_f(v)}"/>'
               for v in py)
    out.extend(f'<line x1="{_f(x0 - tl / 2)}" y1="{_f(v)}" x2="{_f(x0)}" y2="{_f(v)}"/>'
               for v in pminor)
    out.append("</g>")
    return out


def _labels(ax: Axes, box: tuple[float, float, float, float], t: dict[str, Any], px: Any,
            py: Any) -> list[str]:
    """Tick labels, axis labels and the title."""
    x0, y0, w, h = box
    tl = 3.5 * PX_PER_PT
    out = []
    lab_h = 0.0
    if not ax.hide_xticklabels:
        xpt, xrot = t["xpt"], t["xrot"]
        for v, s in zip(px, t["xlab"], strict=True):
            if xrot:
                out.append(svg_text(v, y0 + h + tl + 2, s, xpt, anchor="end", baseline="hanging",
                                 rotate=-xrot))
            else:
                out.append(svg_text(v, y0 + h + tl + 2, s, xpt, baseline="hanging"))
        rot_h = max((_text_width_px(s, xpt) for s in t["xlab"]), default=0.0) * math.sin(
            math.radians(xrot))
        lab_h = tl + 2 + xpt * PX_PER_PT * 1.2 + rot_h
    lab_w = 0.0
    if not ax.hide_yticklabels:
        out.extend(svg_text(x0 - tl - 2, v, s, _FONT_PT, anchor="end", baseline="middle")
                   for v, s in zip(py, t["ylab"], strict=True))
        lab_w = tl + 2 + max((_text_width_px(s, _FONT_PT) for s in t["ylab"]), default=0.0)
    if ax.xlabel:
        out.append(svg_text(x0 + w / 2, y0 + h + lab_h + 2, ax.xlabel, ax._xlabel_pt,
                         baseline="hanging"))
    if ax.ylabel:
        out.append(svg_text(x0 - lab_w - 4, y0 + h / 2, ax.ylabel, ax._ylabel_pt,
                         baseline="auto", rotate=-90))
    if ax.title:
        out.append(svg_text(x0 + w / 2, y0 - 6 * PX_PER_PT, ax.title, ax._title_pt))
    return out


def _annotations(ax: Axes, fx: Mapper, fy: Mapper) -> list[str]:
    out = []
    for an in ax._annotations:
        px, py = float(fx(an["xy"][0])), float(fy(an["xy"][1]))
        if not (np.isfinite(px) and np.isfinite(py)):
            continue
        px += an["off"][0] * PX_PER_PT
        py -= an["off"][1] * PX_PER_PT
        base = {"center": "middle", "top": "hanging", "bottom": "auto"}.get(an["va"], "auto")
        out.append(svg_text(px, py, an["text"], an["pt"], anchor="start", baseline=base,
                         color=an["color"], weight=an["weight"]))
    return out


def draw_axes(ax: Axes, box: tuple[float, float, float, float],
              lims: tuple[tuple[float, float], tuple[float, float]], clip_id: str) -> str:
    """SVG elements of one :class:`pospp.report.svg.Axes` in its pixel ``box`` (x0, y0,
    width, height) with data limits ``lims`` ((xlo, xhi), (ylo, yhi)); ``clip_id`` names its
    clip path (unique in the figure)."""
    x0, y0, w, h = box
    log = ax.yscale == "log"
    fx, fy = _mappers(box, lims, log)
    t = _ticks(ax, box, lims)
    px, py, pminor = fx(t["xt"]), fy(t["yt"]), fy(t["ymin"])
    out = [f'<clipPath id="{clip_id}"><rect x="{_f(x0)}" y="{_f(y0)}" width="{_f(w)}" '
           f'height="{_f(h)}"/></clipPath>']
    if ax._grid is not None:
        out.extend(_grid_lines(ax._grid, box, px, py, pminor))
    out.append(f'<g clip-path="url(#{clip_id})">')  # the artists, clipped to the axes
    for a in ax._artists:
        out.extend(_draw_artist(a, fx, fy, x0, w, log))
    out.append("</g>")
    out.extend(_frame_and_ticks(box, px, py, pminor))
    out.extend(_labels(ax, box, t, px, py))
    out.extend(_annotations(ax, fx, fy))
    if ax._legend is not None:
        out.append(_draw_legend(ax, box, fx, fy))
    return "\n".join(out)


def _log_ticks(lo: float, hi: float) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Decade ticks (labelled 10^k), and the 2..9 minor ticks; a range inside one decade
    gets labelled 1-2-5 ticks instead."""
    a, b = math.floor(math.log10(lo)), math.ceil(math.log10(hi))
    dec = np.arange(a, b + 1)
    step = max(1, math.ceil(len(dec) / 8))
    major = 10.0 ** dec[::step]
    inside = major[(major >= lo * (1 - 1e-9)) & (major <= hi * (1 + 1e-9))]
    minor = np.array([m * 10.0 ** k for k in dec for m in range(2, 10)]) if step == 1 \
        else np.array([])
    minor = minor[(minor >= lo) & (minor <= hi)]
    if len(inside) >= 2:
        labels = [f"10^{{{round(math.log10(v))}}}" for v in inside]
        return inside, labels, minor
    cand = np.array([m * 10.0 ** k for k in dec for m in (1, 2, 5)])
    cand = cand[(cand >= lo) & (cand <= hi)]
    return cand, [f"{v:g}" for v in cand], minor


def _draw_artist(a: dict[str, Any], fx: Mapper, fy: Mapper, x0: float, w: float, log: bool
                 ) -> list[str]:
    k = a["kind"]
    out: list[str] = []
    if k == "line":
        lw = a["lw"] * PX_PER_PT
        px, py = fx(a["x"]), fy(a["y"])
        if a["ls"] not in ("none", "None", ""):
            for pts in _polyline_runs(px, py):
                out.append(f'<polyline points="{pts}" fill="none" '
                           f'{_paint(a["color"], "stroke")} stroke-width="{lw:.2f}"'
                           f'{_dash(a["ls"], lw)} stroke-linejoin="round"/>')
        if a["marker"]:
            col = a["color"][0]
            out.extend(_marker(a["marker"], u, v, a["ms"], col)
                       for u, v in zip(px, py, strict=True) if np.isfinite(u) and np.isfinite(v))
    elif k == "band":
        px, p1, p2 = fx(a["x"]), fy(a["y1"]), fy(a["y2"])
        ok = np.isfinite(px) & np.isfinite(p1) & np.isfinite(p2)
        if ok.any():
            px, p1, p2 = px[ok], p1[ok], p2[ok]
            i_up, i_down = _decimate(px, p2), _decimate(px, p1)[::-1]
            pts = _points(np.r_[px[i_up], px[i_down]], np.r_[p2[i_up], p1[i_down]])
            out.append(f'<polygon points="{pts}" {_paint(a["color"], "fill")} stroke="none"/>')
    elif k == "hline":
        v = float(fy(a["y"]))
        lw = a["lw"] * PX_PER_PT
        if np.isfinite(v):
            out.append(f'<line x1="{_f(x0)}" y1="{_f(v)}" x2="{_f(x0 + w)}" y2="{_f(v)}" '
                       f'{_paint(a["color"], "stroke")} stroke-width="{lw:.2f}"'
                       f'{_dash(a["ls"], lw)}/>')
    elif k == "hspan":
        v0, v1 = float(fy(a["y0"])), float(fy(a["y1"]))
        if np.isfinite(v0) and np.isfinite(v1):
            out.append(f'<rect x="{_f(x0)}" y="{_f(min(v0, v1))}" width="{_f(w)}" '
                       f'height="{_f(abs(v1 - v0))}" {_paint(a["color"], "fill")}/>')
    elif k == "bar":
        for xc, hv in zip(a["x"], a["h"], strict=True):
            if not np.isfinite(hv):
                continue
            left, right = float(fx(xc - a["w"] / 2)), float(fx(xc + a["w"] / 2))
            # from zero (linear) or from far below the axes (log), clipped to the axes
            base = float(fy(0.0)) if not log else float(fy(1e-300))
            top = float(fy(hv))
            if not (np.isfinite(base) and np.isfinite(top)):
                continue
            out.append(f'<rect x="{_f(left)}" y="{_f(min(base, top))}" '
                       f'width="{_f(right - left)}" height="{_f(abs(top - base))}" '
                       f'{_paint(a["color"], "fill")}/>')
    elif k == "errorbar":
        col = a["color"][0]
        cap = a["capsize"] * PX_PER_PT
        for xv, yv, ev in zip(a["x"], a["y"], a["e"], strict=True):
            xe = float(fx(xv))
            lo, hi, mid = float(fy(yv - ev)), float(fy(yv + ev)), float(fy(yv))
            if np.isfinite(lo) and np.isfinite(hi):
                out.append(f'<line x1="{_f(xe)}" y1="{_f(lo)}" x2="{_f(xe)}" y2="{_f(hi)}" '
                           f'stroke="{col}" stroke-width="{1.5 * PX_PER_PT:.2f}"/>')
                if cap:
                    for yy in (lo, hi):
                        out.append(f'<line x1="{_f(xe - cap)}" y1="{_f(yy)}" '
                                   f'x2="{_f(xe + cap)}" y2="{_f(yy)}" stroke="{col}" '
                                   f'stroke-width="{1.5 * PX_PER_PT:.2f}"/>')
            if np.isfinite(mid):
                out.append(_marker(a["marker"], xe, mid, a["ms"], col))
    return out


def _draw_legend(ax: Axes, box: tuple[float, float, float, float], fx: Mapper,
                 fy: Mapper) -> str:
    items = [a for a in ax._artists if a.get("label") and not str(a["label"]).startswith("_")]
    if not items:
        return ""
    leg = ax._legend
    assert leg is not None  # draw_axes draws a legend only when one was asked for
    pt = leg["pt"]
    fs = pt * PX_PER_PT
    ncol = max(1, min(leg["ncol"], len(items)))
    nrow = -(-len(items) // ncol)
    handle = 2.0 * fs
    col_w = [max(_text_width_px(str(a["label"]), pt) for a in items[c::ncol]) + handle + 0.8 * fs
             for c in range(ncol)]
    bw = sum(col_w) + 0.8 * fs
    bh = nrow * 1.3 * fs + 0.6 * fs
    x0, y0, w, h = box
    pad = 0.5 * fs
    corners = {"upper right": (x0 + w - bw - pad, y0 + pad),
               "upper left": (x0 + pad, y0 + pad),
               "lower left": (x0 + pad, y0 + h - bh - pad),
               "lower right": (x0 + w - bw - pad, y0 + h - bh - pad),
               "center right": (x0 + w - bw - pad, y0 + (h - bh) / 2),
               "center left": (x0 + pad, y0 + (h - bh) / 2),
               "upper center": (x0 + (w - bw) / 2, y0 + pad),
               "lower center": (x0 + (w - bw) / 2, y0 + h - bh - pad)}
    if leg["loc"] in corners:
        lx, ly = corners[leg["loc"]]
    else:  # "best": the corner covering the least of the lines (sampled along each)
        pts = []
        for a in ax._artists:
            if a["kind"] in ("line", "errorbar") and len(a["x"]):
                u = np.linspace(0.0, len(a["x"]) - 1.0, 400)
                k = np.arange(len(a["x"]), dtype=float)
                pts.append((np.interp(u, k, fx(a["x"])), np.interp(u, k, fy(a["y"]))))
        px = np.concatenate([p[0] for p in pts]) if pts else np.array([])
        py = np.concatenate([p[1] for p in pts]) if pts else np.array([])
        best: tuple[int, float, float] | None = None
        for name in corners:  # matplotlib's order of preference
            cx, cy = corners[name]
            n = int(np.sum((px >= cx) & (px <= cx + bw) & (py >= cy) & (py <= cy + bh)))
            if best is None or n < best[0]:
                best = (n, cx, cy)
        assert best is not None  # corners is never empty
        _, lx, ly = best
    out = [f'<g><rect x="{_f(lx)}" y="{_f(ly)}" width="{_f(bw)}" height="{_f(bh)}" '
           'fill="#ffffff" fill-opacity="0.8" stroke="#cccccc" rx="3"/>']
    for i, a in enumerate(items):
        c, r = i % ncol, i // ncol
        hx = lx + 0.4 * fs + sum(col_w[:c])
        hy = ly + 0.3 * fs + (r + 0.5) * 1.3 * fs
        col = a["color"]
        if a["kind"] in ("line", "hline"):
            lw = a["lw"] * PX_PER_PT
            if a["ls"] not in ("none", "None", ""):
                out.append(f'<line x1="{_f(hx)}" y1="{_f(hy)}" x2="{_f(hx + handle)}" '
                           f'y2="{_f(hy)}" {_paint(col, "stroke")} stroke-width="{lw:.2f}"'
                           f'{_dash(a["ls"], lw)}/>')
            if a.get("marker"):
                out.append(_marker(a["marker"], hx + handle / 2, hy, a["ms"], col[0]))
        elif a["kind"] == "errorbar":
            out.append(_marker(a["marker"], hx + handle / 2, hy, a["ms"], col[0]))
        else:
            out.append(f'<rect x="{_f(hx)}" y="{_f(hy - 0.35 * fs)}" width="{_f(handle)}" '
                       f'height="{_f(0.7 * fs)}" {_paint(col, "fill")}/>')
        out.append(svg_text(hx + handle + 0.4 * fs, hy, str(a["label"]), pt, anchor="start",
                         baseline="middle"))
    out.append("</g>")
    return "\n".join(out)
