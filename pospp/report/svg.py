"""A small SVG drawing backend for the report's figures (no matplotlib at run time).

The report's figures (:mod:`pospp.report.figures`) are line, band, bar and error-bar plots
with titles, labels, legends and grids. Drawing them with matplotlib's Agg backend took
1.7-2.4 s of a sample run (per-artist Python: ticks, text layout) plus 0.7 s to import it
(docs/benchmarks.md, issue 18); writing the same content as SVG text from numpy takes a few
milliseconds per figure, and the browser draws it (vector: sharp at any zoom).

Only the subset of matplotlib's ``Axes`` interface the report uses is implemented, with the
same names and meanings, so that one function in :mod:`pospp.report.figures` draws either
way: ``plot``/``semilogy`` (format strings such as ``"o-"``, ``"ko-"``), ``fill_between``,
``axhline``, ``axhspan``, ``bar``, ``errorbar``, ``annotate`` (offset in points),
``set_title``/``set_xlabel``/``set_ylabel``, ``grid``, ``legend``, ``set_xticks``,
``set_xlim``, ``set_yscale("log")``, ``set_aspect("equal", adjustable="datalim")``; and of
``Figure``: ``subplots_adjust`` and ``suptitle``. Sizes are matplotlib's (inches at
:data:`DPI`, points at 72 per inch) and its defaults (10 pt text, 12 pt titles, 5 % data
margins, the tab10 colour cycle).

Axis mapping: a data value ``v`` on an axis with limits ``lo, hi`` over ``[p0, p0 + L]``
pixels is drawn at ``p0 + L (t(v) - t(lo)) / (t(hi) - t(lo))`` with ``t`` the identity
(linear) or log10 (log); y grows upwards. No I/O here: :meth:`Figure.to_svg` returns text.
"""

from __future__ import annotations

import html
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

DPI = 80.0
"""Pixels per inch of the drawing (the PNG figures were saved at 80 dpi)."""
_PX_PER_PT = DPI / 72.0
_FONT_PT = 10.0
_TITLE_PT = 12.0
_TAB10 = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
          "#7f7f7f", "#bcbd22", "#17becf")
_NAMED = {"k": "#000000", "w": "#ffffff", "r": "#ff0000", "g": "#008000", "b": "#0000ff",
          "black": "#000000", "white": "#ffffff", "red": "#ff0000", "grey": "#808080",
          "gray": "#808080"}
_DASHES = {"-": None, "solid": None, "--": (3.7, 1.6), "dashed": (3.7, 1.6),
           ":": (1.0, 1.65), "dotted": (1.0, 1.65), "-.": (6.4, 1.6, 1.0, 1.6),
           "dashdot": (6.4, 1.6, 1.0, 1.6)}
_FONT = "DejaVu Sans,Helvetica,Arial,sans-serif"
_SIZES = {"xx-small": 5.79, "x-small": 6.94, "small": 8.33, "medium": 10.0, "large": 12.0,
          "x-large": 14.4, "xx-large": 17.28}


def _pt(size: float | str | None, default: float) -> float:
    if size is None:
        return default
    return _SIZES[size] if isinstance(size, str) else float(size)


def color_hex(color: Any, cycle_index: int = 0) -> tuple[str, float]:
    """(``#rrggbb``, alpha) of a matplotlib colour spec: RGB(A) tuple of floats in [0, 1],
    ``"C3"``, a grey level string ``"0.6"``, a hex string or a basic name; None picks
    ``cycle_index`` of the tab10 cycle."""
    if color is None:
        return _TAB10[cycle_index % 10], 1.0
    if isinstance(color, str):
        if len(color) == 2 and color[0] == "C" and color[1].isdigit():
            return _TAB10[int(color[1])], 1.0
        if color.startswith("#"):
            return color.lower(), 1.0
        if color in _NAMED:
            return _NAMED[color], 1.0
        g = float(color)  # grey level
        v = round(255 * g)
        return f"#{v:02x}{v:02x}{v:02x}", 1.0
    c = tuple(float(v) for v in color)
    return ("#" + "".join(f"{round(255 * v):02x}" for v in c[:3]),
            c[3] if len(c) > 3 else 1.0)


def _parse_fmt(fmt: str) -> tuple[str | None, str | None, str | None]:
    """(color, marker, linestyle) of a matplotlib format string such as ``"ko-"``."""
    color = marker = ls = None
    rest = fmt
    for style in ("--", "-.", "-", ":"):
        if style in rest:
            ls = style
            rest = rest.replace(style, "", 1)
            break
    for ch in rest:
        if ch in "os^v.":
            marker = ch
        elif ch in "kwrgbcmy":
            color = ch if ch in _NAMED else {"c": "#00bfbf", "m": "#bf00bf",
                                            "y": "#bfbf00"}[ch]
    if marker is not None and ls is None:
        ls = "none"
    return color, marker, ls


def _num(a: Any) -> np.ndarray:
    return np.asarray(a, dtype=float).ravel()


def _f(v: float) -> str:
    """A pixel coordinate as short text (0.1 px)."""
    return f"{v:.1f}"


def _text(x: float, y: float, s: str, size_pt: float, *, anchor: str = "middle",
          baseline: str = "auto", color: str = "#000000", weight: str | None = None,
          rotate: float = 0.0) -> str:
    tr = f' transform="rotate({rotate:g} {_f(x)} {_f(y)})"' if rotate else ""
    wt = f' font-weight="{weight}"' if weight else ""
    fill = "" if color == "#000000" else f' fill="{color}"'
    return (f'<text x="{_f(x)}" y="{_f(y)}" font-size="{size_pt * _PX_PER_PT:.1f}" '
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
    return 0.6 * size_pt * _PX_PER_PT * len(s)


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


class Axes:
    """One plotting area; matplotlib-named methods record artists, the figure draws them."""

    def __init__(self, fig: Figure, row: int, col: int) -> None:
        self.figure, self.row, self.col = fig, row, col
        self._artists: list[dict[str, Any]] = []
        self._cycle = 0
        self.title = self.xlabel = self.ylabel = ""
        self._title_pt = _TITLE_PT
        self._xlabel_pt = self._ylabel_pt = _FONT_PT
        self.yscale = "linear"
        self._grid: dict[str, Any] | None = None
        self._legend: dict[str, Any] | None = None
        self._xticks: dict[str, Any] | None = None
        self._xlim: tuple[float, float] | None = None
        self._aspect_equal = False
        self._annotations: list[dict[str, Any]] = []
        self.sharex: list[Axes] = [self]
        self.sharey: list[Axes] = [self]
        self.hide_xticklabels = self.hide_yticklabels = False

    # --- artists ------------------------------------------------------------------------------
    def _next_color(self, color: Any) -> tuple[str, float]:
        if color is None:
            c = color_hex(None, self._cycle)
            self._cycle += 1
            return c
        return color_hex(color)

    def plot(self, *args: Any, color: Any = None, lw: float | None = None,
             linewidth: float | None = None, ls: str | None = None,
             linestyle: str | None = None, label: str | None = None, ms: float | None = None,
             markersize: float | None = None, marker: str | None = None) -> None:
        fmt = args[-1] if args and isinstance(args[-1], str) else ""
        data = args[:-1] if fmt else args
        if len(data) == 1:
            y = _num(data[0])
            x = np.arange(len(y), dtype=float)
        else:
            x, y = _num(data[0]), _num(data[1])
        fcolor, fmarker, fls = _parse_fmt(fmt)
        style = ls or linestyle or fls or "-"
        self._artists.append({
            "kind": "line", "x": x, "y": y, "color": self._next_color(color or fcolor),
            "lw": float(lw or linewidth or 1.5), "ls": style, "label": label,
            "marker": marker or fmarker, "ms": float(ms or markersize or 6.0)})

    def semilogy(self, *args: Any, **kw: Any) -> None:
        self.yscale = "log"
        self.plot(*args, **kw)

    def fill_between(self, x: Any, y1: Any, y2: Any, *, color: Any = None, alpha: float = 1.0,
                     lw: float = 0.0, label: str | None = None) -> None:
        c, a = self._next_color(color)
        self._artists.append({"kind": "band", "x": _num(x), "y1": _num(y1) * np.ones(len(_num(x))),
                              "y2": _num(y2) * np.ones(len(_num(x))), "color": (c, a * alpha),
                              "label": label})

    def axhline(self, y: float, *, color: Any = None, ls: str = "-", lw: float = 1.5,
                label: str | None = None) -> None:
        self._artists.append({"kind": "hline", "y": float(y), "color": self._next_color(color),
                              "ls": ls, "lw": float(lw), "label": label, "marker": None})

    def axhspan(self, y0: float, y1: float, *, color: Any = None, alpha: float = 1.0) -> None:
        c, a = self._next_color(color)
        self._artists.append({"kind": "hspan", "y0": float(y0), "y1": float(y1),
                              "color": (c, a * alpha), "label": None})

    def bar(self, x: Any, height: Any, width: float = 0.8, *, label: str | None = None,
            color: Any = None) -> None:
        self._artists.append({"kind": "bar", "x": _num(x), "h": _num(height),
                              "w": float(width), "color": self._next_color(color),
                              "label": label})

    def errorbar(self, x: Any, y: Any, yerr: Any = None, *, fmt: str = "o", ms: float = 6.0,
                 capsize: float = 0.0, color: Any = None, label: str | None = None) -> None:
        fcolor, marker, _ = _parse_fmt(fmt)
        x, y = _num(x), _num(y)
        e = np.zeros_like(y) if yerr is None else _num(yerr) * np.ones_like(y)
        self._artists.append({"kind": "errorbar", "x": x, "y": y, "e": e,
                              "color": self._next_color(color or fcolor),
                              "marker": marker or "o", "ms": float(ms),
                              "capsize": float(capsize), "label": label})

    def annotate(self, text: str, xy: tuple[float, float], *, fontsize: float | str = 10.0,
                 color: Any = None, xytext: tuple[float, float] = (0.0, 0.0),
                 textcoords: str = "offset points", va: str = "baseline",
                 weight: str | None = None) -> None:
        if textcoords != "offset points":
            raise ValueError("only textcoords='offset points' is drawn")
        self._annotations.append({"text": str(text), "xy": (float(xy[0]), float(xy[1])),
                                  "pt": _pt(fontsize, _FONT_PT),
                                  "color": color_hex(color or "k")[0], "off": xytext,
                                  "va": va, "weight": weight})

    # --- decorations --------------------------------------------------------------------------
    def set_title(self, text: str, fontsize: float | str | None = None) -> None:
        self.title, self._title_pt = str(text), _pt(fontsize, _TITLE_PT)

    def set_xlabel(self, text: str, fontsize: float | str | None = None) -> None:
        self.xlabel, self._xlabel_pt = str(text), _pt(fontsize, _FONT_PT)

    def set_ylabel(self, text: str, fontsize: float | str | None = None) -> None:
        self.ylabel, self._ylabel_pt = str(text), _pt(fontsize, _FONT_PT)

    def get_ylabel(self) -> str:
        return self.ylabel

    def set_yscale(self, scale: str) -> None:
        if scale not in ("linear", "log"):
            raise ValueError(f"y scale {scale!r} is not drawn (linear, log)")
        self.yscale = scale

    def set_xlim(self, lo: float, hi: float) -> None:
        self._xlim = (float(lo), float(hi))

    def set_aspect(self, aspect: str, adjustable: str = "datalim") -> None:
        self._aspect_equal = aspect == "equal"

    def grid(self, visible: bool = True, *, alpha: float = 1.0, which: str = "major") -> None:
        self._grid = {"alpha": float(alpha), "which": which} if visible else None

    def legend(self, *, fontsize: float | str | None = None, ncol: int = 1,
               loc: str = "best") -> None:
        self._legend = {"pt": _pt(fontsize, _FONT_PT), "ncol": int(ncol), "loc": loc}

    def set_xticks(self, ticks: Any, labels: Sequence[Any] | None = None, *,
                   fontsize: float | str | None = None, rotation: float = 0.0) -> None:
        t = _num(ticks)
        lab = [str(v) for v in labels] if labels is not None else None
        self._xticks = {"ticks": t, "labels": lab, "pt": _pt(fontsize, _FONT_PT),
                        "rotation": float(rotation)}

    # --- limits -------------------------------------------------------------------------------
    def _data_limits(self) -> tuple[list[float], list[float]]:
        xs: list[np.ndarray] = []
        ys: list[np.ndarray] = []
        for a in self._artists:
            k = a["kind"]
            if k == "line":
                xs.append(a["x"])
                ys.append(a["y"])
            elif k == "band":
                xs.append(a["x"])
                ys.extend((a["y1"], a["y2"]))
            elif k in ("hline", "hspan"):
                ys.append(np.array([a["y"]] if k == "hline" else [a["y0"], a["y1"]]))
            elif k == "bar":
                xs.append(np.r_[a["x"] - a["w"] / 2, a["x"] + a["w"] / 2])
                ys.append(np.r_[a["h"], 0.0])
            elif k == "errorbar":
                xs.append(a["x"])
                ys.extend((a["y"] - a["e"], a["y"] + a["e"]))

        def span(parts: list[np.ndarray], log: bool) -> list[float]:
            v = np.concatenate(parts) if parts else np.array([])
            v = v[np.isfinite(v) & ((v > 0) if log else True)]
            return [float(v.min()), float(v.max())] if len(v) else []

        return span(xs, False), span(ys, self.yscale == "log")


def _pad(lim: list[float], log: bool, margin: float = 0.05) -> tuple[float, float]:
    if not lim:
        return (1.0, 10.0) if log else (0.0, 1.0)
    lo, hi = lim
    if log:
        a, b = math.log10(lo), math.log10(hi)
        if b - a < 1e-12:
            a, b = a - 0.5, b + 0.5
        d = (b - a) * margin
        return 10.0 ** (a - d), 10.0 ** (b + d)
    if hi - lo <= 1e-300 or hi - lo < 1e-12 * max(abs(lo), abs(hi)):
        d = abs(lo) * 0.05 if lo != 0 else 0.05
        return lo - d, hi + d
    d = (hi - lo) * margin
    return lo - d, hi + d


class Figure:
    """A figure of ``nrows x ncols`` axes, ``figsize`` in inches (drawn at :data:`DPI`)."""

    def __init__(self, figsize: tuple[float, float]) -> None:
        self.width_px, self.height_px = figsize[0] * DPI, figsize[1] * DPI
        self.axes: list[Axes] = []
        self._grid_shape = (1, 1)
        self._adjust = {"left": 0.125, "right": 0.9, "bottom": 0.11, "top": 0.88,
                        "wspace": 0.2, "hspace": 0.2}
        self._suptitle: tuple[str, float] | None = None

    def subplots_adjust(self, **kw: float) -> None:
        self._adjust.update({k: float(v) for k, v in kw.items() if v is not None})

    def suptitle(self, text: str, fontsize: float | str | None = None) -> None:
        self._suptitle = (str(text), _pt(fontsize, _TITLE_PT))

    def clf(self) -> None:
        self.axes = []

    # --- drawing ------------------------------------------------------------------------------
    def _boxes(self) -> dict[int, tuple[float, float, float, float]]:
        nr, nc = self._grid_shape
        a = self._adjust
        w_all = (a["right"] - a["left"]) * self.width_px
        h_all = (a["top"] - a["bottom"]) * self.height_px
        cw = w_all / (nc + a["wspace"] * (nc - 1))
        ch = h_all / (nr + a["hspace"] * (nr - 1))
        out = {}
        for ax in self.axes:
            x0 = a["left"] * self.width_px + ax.col * cw * (1 + a["wspace"])
            y0 = (1 - a["top"]) * self.height_px + ax.row * ch * (1 + a["hspace"])
            out[id(ax)] = (x0, y0, cw, ch)
        return out

    def _limits(self, boxes: dict[int, tuple[float, float, float, float]]
                ) -> dict[int, tuple[tuple[float, float], tuple[float, float]]]:
        raw = {id(ax): ax._data_limits() for ax in self.axes}
        out = {}
        for ax in self.axes:
            xl = [v for o in ax.sharex for v in raw[id(o)][0]]
            yl = [v for o in ax.sharey for v in raw[id(o)][1]]
            xlim = next((o._xlim for o in ax.sharex if o._xlim is not None), None)
            xr = xlim if xlim is not None else _pad([min(xl), max(xl)] if xl else [], False)
            yr = _pad([min(yl), max(yl)] if yl else [], ax.yscale == "log")
            if ax._aspect_equal and ax.yscale == "linear":
                _, _, w, h = boxes[id(ax)]
                ux, uy = (xr[1] - xr[0]) / w, (yr[1] - yr[0]) / h  # data units per pixel
                u = max(ux, uy)
                cx, cy = sum(xr) / 2, sum(yr) / 2
                xr = (cx - u * w / 2, cx + u * w / 2)
                yr = (cy - u * h / 2, cy + u * h / 2)
            out[id(ax)] = (xr, yr)
        return out

    def to_svg(self) -> str:
        """The figure as one standalone SVG document (text)."""
        w, h = self.width_px, self.height_px
        parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{w:.0f}" height="{h:.0f}" '
                 f'viewBox="0 0 {w:.0f} {h:.0f}" font-family="{_FONT}">',
                 f'<rect width="{w:.0f}" height="{h:.0f}" fill="#ffffff"/>']
        boxes = self._boxes()
        limits = self._limits(boxes)
        for i, ax in enumerate(self.axes):
            parts.append(_draw_axes(ax, boxes[id(ax)], limits[id(ax)], f"c{i}"))
        if self._suptitle is not None:
            text, pt = self._suptitle
            parts.append(_text(w / 2, 0.02 * h + pt * _PX_PER_PT, text, pt))
        parts.append("</svg>")
        return "\n".join(parts)


def subplots(nrows: int = 1, ncols: int = 1, *, figsize: tuple[float, float] = (6.4, 4.8),
             sharex: bool | str = False, sharey: bool | str = False,
             squeeze: bool = True) -> tuple[Figure, Any]:
    """``matplotlib.pyplot.subplots`` for this backend: (figure, axes) with the same shapes
    (one Axes, a 1-D or a 2-D object array)."""
    fig = Figure(figsize)
    fig._grid_shape = (nrows, ncols)
    grid = np.empty((nrows, ncols), dtype=object)
    for r in range(nrows):
        for c in range(ncols):
            grid[r, c] = Axes(fig, r, c)
            fig.axes.append(grid[r, c])

    def groups(share: bool | str, by_row: bool) -> list[list[Axes]]:
        if share is True or share == "all":
            return [list(grid.ravel())]
        if share == "col":
            return [list(grid[:, c]) for c in range(ncols)]
        if share == "row":
            return [list(grid[r, :]) for r in range(nrows)]
        return []

    for g in groups(sharex, False):
        for ax in g:
            ax.sharex = g
            ax.hide_xticklabels = ax.row < nrows - 1
    for g in groups(sharey, True):
        for ax in g:
            ax.sharey = g
            ax.hide_yticklabels = sharey in (True, "all", "row") and ax.col > 0
    if not squeeze:
        return fig, grid
    if nrows == 1 and ncols == 1:
        return fig, grid[0, 0]
    return fig, grid.ravel() if nrows == 1 or ncols == 1 else grid


# --- drawing one axes -------------------------------------------------------------------------

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
    r = ms_pt * _PX_PER_PT / 2
    if kind == "s":
        return (f'<rect x="{_f(x - r)}" y="{_f(y - r)}" width="{_f(2 * r)}" '
                f'height="{_f(2 * r)}" fill="{fill}"/>')
    if kind == ".":
        r /= 2
    return f'<circle cx="{_f(x)}" cy="{_f(y)}" r="{r:.1f}" fill="{fill}"/>'


def _draw_axes(ax: Axes, box: tuple[float, float, float, float],
               lims: tuple[tuple[float, float], tuple[float, float]], clip_id: str) -> str:
    x0, y0, w, h = box
    (xlo, xhi), (ylo, yhi) = lims
    log = ax.yscale == "log"
    tlo, thi = (math.log10(ylo), math.log10(yhi)) if log else (ylo, yhi)

    def fx(v: Any) -> Any:
        return x0 + (np.asarray(v, dtype=float) - xlo) / (xhi - xlo) * w

    def fy(v: Any) -> Any:
        v = np.asarray(v, dtype=float)
        if log:
            with np.errstate(divide="ignore", invalid="ignore"):
                v = np.where(v > 0, np.log10(np.where(v > 0, v, 1.0)), np.nan)
        return y0 + h - (v - tlo) / (thi - tlo) * h

    out = [f'<clipPath id="{clip_id}"><rect x="{_f(x0)}" y="{_f(y0)}" width="{_f(w)}" '
           f'height="{_f(h)}"/></clipPath>']
    # ticks
    if ax._xticks is not None:
        xt = ax._xticks["ticks"]
        xlab = ax._xticks["labels"] or _linear_labels(xt)
        xpt, xrot = ax._xticks["pt"], ax._xticks["rotation"]
        inside = (xt >= xlo - 1e-9 * abs(xhi - xlo)) & (xt <= xhi + 1e-9 * abs(xhi - xlo))
        xt, xlab = xt[inside], [s for s, k in zip(xlab, inside, strict=True) if k]
    else:
        xt = _nice_ticks(xlo, xhi, int(np.clip(w / 50, 3, 9)))
        xlab, xpt, xrot = _linear_labels(xt), _FONT_PT, 0.0
    if log:
        yt, ylab, ymin = _log_ticks(ylo, yhi)
    else:
        yt = _nice_ticks(ylo, yhi, int(np.clip(h / 32, 3, 8)))
        ylab, ymin = _linear_labels(yt), np.array([])
    grid = ax._grid
    if grid is not None:
        g = [f'<g stroke="#b0b0b0" stroke-width="{0.8 * _PX_PER_PT:.2f}" '
             f'stroke-opacity="{grid["alpha"]:.3g}">']
        for v in fx(xt):
            g.append(f'<line x1="{_f(v)}" y1="{_f(y0)}" x2="{_f(v)}" y2="{_f(y0 + h)}"/>')
        for v in fy(yt):
            g.append(f'<line x1="{_f(x0)}" y1="{_f(v)}" x2="{_f(x0 + w)}" y2="{_f(v)}"/>')
        if grid["which"] == "both":
            for v in fy(ymin):
                g.append(f'<line x1="{_f(x0)}" y1="{_f(v)}" x2="{_f(x0 + w)}" y2="{_f(v)}" '
                         'stroke-width="0.5"/>')
        g.append("</g>")
        out.extend(g)
    # artists, clipped to the axes
    out.append(f'<g clip-path="url(#{clip_id})">')
    for a in ax._artists:
        out.extend(_draw_artist(a, fx, fy, x0, w, log))
    out.append("</g>")
    # frame and ticks
    out.append(f'<rect x="{_f(x0)}" y="{_f(y0)}" width="{_f(w)}" height="{_f(h)}" '
               f'fill="none" stroke="#000000" stroke-width="{0.8 * _PX_PER_PT:.2f}"/>')
    tl = 3.5 * _PX_PER_PT
    tk = [f'<g stroke="#000000" stroke-width="{0.8 * _PX_PER_PT:.2f}">']
    for v in fx(xt):
        tk.append(f'<line x1="{_f(v)}" y1="{_f(y0 + h)}" x2="{_f(v)}" y2="{_f(y0 + h + tl)}"/>')
    for v in fy(yt):
        tk.append(f'<line x1="{_f(x0 - tl)}" y1="{_f(v)}" x2="{_f(x0)}" y2="{_f(v)}"/>')
    for v in fy(ymin):
        tk.append(f'<line x1="{_f(x0 - tl / 2)}" y1="{_f(v)}" x2="{_f(x0)}" y2="{_f(v)}"/>')
    tk.append("</g>")
    out.extend(tk)
    lab_h = 0.0
    if not ax.hide_xticklabels:
        for v, s in zip(fx(xt), xlab, strict=True):
            ty = y0 + h + tl + 2
            if xrot:
                out.append(_text(v, ty, s, xpt, anchor="end", baseline="hanging",
                                 rotate=-xrot))
            else:
                out.append(_text(v, ty, s, xpt, baseline="hanging"))
        rot_h = max((_text_width_px(s, xpt) for s in xlab), default=0.0) * math.sin(
            math.radians(xrot))
        lab_h = tl + 2 + xpt * _PX_PER_PT * 1.2 + rot_h
    lab_w = 0.0
    if not ax.hide_yticklabels:
        for v, s in zip(fy(yt), ylab, strict=True):
            out.append(_text(x0 - tl - 2, v, s, _FONT_PT, anchor="end", baseline="middle"))
        lab_w = tl + 2 + max((_text_width_px(s, _FONT_PT) for s in ylab), default=0.0)
    if ax.xlabel:
        out.append(_text(x0 + w / 2, y0 + h + lab_h + 2, ax.xlabel, ax._xlabel_pt,
                         baseline="hanging"))
    if ax.ylabel:
        yx = x0 - lab_w - 4
        out.append(_text(yx, y0 + h / 2, ax.ylabel, ax._ylabel_pt, baseline="auto",
                         rotate=-90))
    if ax.title:
        out.append(_text(x0 + w / 2, y0 - 6 * _PX_PER_PT, ax.title, ax._title_pt))
    for an in ax._annotations:
        px, py = float(fx(an["xy"][0])), float(fy(an["xy"][1]))
        if not (np.isfinite(px) and np.isfinite(py)):
            continue
        px += an["off"][0] * _PX_PER_PT
        py -= an["off"][1] * _PX_PER_PT
        base = {"center": "middle", "top": "hanging", "bottom": "auto"}.get(an["va"], "auto")
        out.append(_text(px, py, an["text"], an["pt"], anchor="start", baseline=base,
                         color=an["color"], weight=an["weight"]))
    if ax._legend is not None:
        out.append(_draw_legend(ax, (x0, y0, w, h), fx, fy))
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


def _draw_artist(a: dict[str, Any], fx: Any, fy: Any, x0: float, w: float, log: bool
                 ) -> list[str]:
    k = a["kind"]
    out: list[str] = []
    if k == "line":
        lw = a["lw"] * _PX_PER_PT
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
            up, lo = _decimate(px, p2), _decimate(px, p1)[::-1]
            pts = _points(np.r_[px[up], px[lo]], np.r_[p2[up], p1[lo]])
            out.append(f'<polygon points="{pts}" {_paint(a["color"], "fill")} stroke="none"/>')
    elif k == "hline":
        v = float(fy(a["y"]))
        lw = a["lw"] * _PX_PER_PT
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
        cap = a["capsize"] * _PX_PER_PT
        for xv, yv, ev in zip(a["x"], a["y"], a["e"], strict=True):
            px = float(fx(xv))
            lo, hi, mid = float(fy(yv - ev)), float(fy(yv + ev)), float(fy(yv))
            if np.isfinite(lo) and np.isfinite(hi):
                out.append(f'<line x1="{_f(px)}" y1="{_f(lo)}" x2="{_f(px)}" y2="{_f(hi)}" '
                           f'stroke="{col}" stroke-width="{1.5 * _PX_PER_PT:.2f}"/>')
                if cap:
                    for yy in (lo, hi):
                        out.append(f'<line x1="{_f(px - cap)}" y1="{_f(yy)}" '
                                   f'x2="{_f(px + cap)}" y2="{_f(yy)}" stroke="{col}" '
                                   f'stroke-width="{1.5 * _PX_PER_PT:.2f}"/>')
            if np.isfinite(mid):
                out.append(_marker(a["marker"], px, mid, a["ms"], col))
    return out


def _draw_legend(ax: Axes, box: tuple[float, float, float, float], fx: Any, fy: Any) -> str:
    items = [a for a in ax._artists if a.get("label") and not str(a["label"]).startswith("_")]
    if not items:
        return ""
    leg = ax._legend
    pt = leg["pt"]
    fs = pt * _PX_PER_PT
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
        best = None
        for name in corners:  # matplotlib's order of preference
            cx, cy = corners[name]
            n = int(np.sum((px >= cx) & (px <= cx + bw) & (py >= cy) & (py <= cy + bh)))
            if best is None or n < best[0]:
                best = (n, cx, cy)
        _, lx, ly = best
    out = [f'<g><rect x="{_f(lx)}" y="{_f(ly)}" width="{_f(bw)}" height="{_f(bh)}" '
           'fill="#ffffff" fill-opacity="0.8" stroke="#cccccc" rx="3"/>']
    for i, a in enumerate(items):
        c, r = i % ncol, i // ncol
        hx = lx + 0.4 * fs + sum(col_w[:c])
        hy = ly + 0.3 * fs + (r + 0.5) * 1.3 * fs
        col = a["color"]
        if a["kind"] in ("line", "hline"):
            lw = a["lw"] * _PX_PER_PT
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
        out.append(_text(hx + handle + 0.4 * fs, hy, str(a["label"]), pt, anchor="start",
                         baseline="middle"))
    out.append("</g>")
    return "\n".join(out)
