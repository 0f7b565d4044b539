"""A small SVG drawing backend for the report's figures (no matplotlib at run time).

The report's figures (:mod:`pospp.report.figures`) are line, band, bar and error-bar plots
with titles, labels, legends and grids, written as SVG text from numpy (a few milliseconds per
figure, against seconds for matplotlib's Agg and its import: docs/history/speed_rounds.md);
the browser draws them (vector: sharp at any zoom).

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

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from pospp.report._svg_draw import DPI, PX_PER_PT, draw_axes, svg_text

_FONT_PT = 10.0
_TITLE_PT = 12.0
_TAB10 = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
          "#7f7f7f", "#bcbd22", "#17becf")
_NAMED = {"k": "#000000", "w": "#ffffff", "r": "#ff0000", "g": "#008000", "b": "#0000ff",
          "black": "#000000", "white": "#ffffff", "red": "#ff0000", "grey": "#808080",
          "gray": "#808080"}
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
            parts.append(draw_axes(ax, boxes[id(ax)], limits[id(ax)], f"c{i}"))
        if self._suptitle is not None:
            text, pt = self._suptitle
            parts.append(svg_text(w / 2, 0.02 * h + pt * PX_PER_PT, text, pt))
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
