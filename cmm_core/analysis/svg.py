"""Plotly figures drawn as static SVG: the product's one SVG writer (issue 27).

A Plotly chart costs the browser its 4.7 MB of script on the first chart of a session and
then some 0.1-0.5 s of drawing per figure (a grid of 21 error functions well over a
second on a small machine); a rerun that changes the model (Add this effect, Undo) draws
every figure of the page again. The app's figures that need no zoom are therefore drawn
here as plain SVG, from the same ``go.Figure`` the core builds (the report keeps Plotly),
so what is shown stays one definition. Hovering a marker shows its label and value (an
SVG ``<title>``); the sidebar's "Interactive plots" switch brings Plotly back. The Data
page's first screen, the placements in three views of the machine volume
(:func:`placement_views_svg`), is such a figure too.

The subset drawn is what ``cmm_core.analysis.figures`` uses for 2-D charts: scatter traces
(markers: circle, square, diamond, triangle-up, x, cross, filled, ``-open`` and ``-dot``;
lines, ``fill="toself"`` bands, dashes) on subplots (``make_subplots``: axis domains,
anchors, shared axes, ``scaleanchor``), heatmaps and grouped bars, axis titles, tick values
given as arrays, subplot titles and other annotations, rectangles (filled, or outlined with
a dash), the figure title and the legend. Anything else (3-D) is not drawn here:
:func:`svg_supported` says whether a figure is within the subset.
"""

from __future__ import annotations

import html
import itertools
import math
import re

import numpy as np
from plotly.colors import get_colorscale, sample_colorscale

from ..io import Dataset
from .figures import COLORWAY, fig_placement_views

__all__ = ["figure_svg", "nice_ticks", "placement_views_svg", "svg_supported", "tick_label"]

_FONT = "font-family=\"'Source Sans Pro', sans-serif\""
_LEGEND_ROW_PX = 22
_CLIP_IDS = itertools.count()
"""Clip-path ids unique in the server's life: several figures share one page's DOM."""


def svg_supported(fig) -> bool:
    """Whether every trace of ``fig`` is a 2-D scatter, a heatmap or bars (what
    :func:`figure_svg` draws)."""
    return all(t.type in ("scatter", "heatmap", "bar") for t in fig.data)


def _edges(centres) -> np.ndarray:
    """Cell edges of a heatmap from its cell centres (halfway between, half a step out)."""
    c = np.asarray(centres, float)
    if c.size < 2:
        return np.array([c[0] - 0.5, c[0] + 0.5]) if c.size else np.array([0.0, 1.0])
    mid = (c[1:] + c[:-1]) / 2
    return np.r_[c[0] - (mid[0] - c[0]), mid, c[-1] + (c[-1] - mid[-1])]


def _z_limits(t, z: np.ndarray) -> tuple[float, float]:
    fin = z[np.isfinite(z)]
    lo, hi = (float(fin.min()), float(fin.max())) if fin.size else (0.0, 1.0)
    if t.zmin is not None and t.zmax is not None:
        return float(t.zmin), float(t.zmax)
    if t.zmid is not None:
        half = max(abs(lo - t.zmid), abs(hi - t.zmid)) or 1.0
        return t.zmid - half, t.zmid + half
    return (lo, hi) if hi > lo else (lo - 1.0, hi + 1.0)


def _colours(t, frac: np.ndarray) -> list:
    """Colours of a heatmap's colour scale at fractions ``frac`` (0-1) of its range."""
    scale = t.colorscale or "Plasma"  # Plotly's default sequential scale
    if isinstance(scale, str):
        scale = get_colorscale(scale)
    scale = [list(x) for x in scale]
    if t.reversescale:
        scale = [[1 - f, c] for f, c in reversed(scale)]
    return sample_colorscale(scale, list(np.clip(frac, 0, 1)))


def tick_label(v: float, step: float) -> str:
    """A tick label with the decimals the tick step needs (no "0.30000000000000004")."""
    step = abs(step)
    if v == 0 or abs(v) < 1e-9 * step:  # the zero tick, summed to 1e-19
        return "0"
    dec = _decimals(step)
    if step and (step < 1e-4 or step >= 1e5):
        # exponent form, chosen by the step (one form on an axis), with the significant
        # digits the step needs: 99990 and 1e5 apart, 2.5e+05 never "2e+05"
        scale = math.floor(math.log10(step) + 1e-9)
        places = max(0, math.floor(math.log10(abs(v)) + 1e-9) - scale
                     + _decimals(step / 10.0 ** scale))
        text = f"{v:.{places}e}"
    else:
        text = f"{v:.{dec}f}"
    return "−" + text[1:] if text.startswith("-") else text


def _decimals(step: float) -> int:
    """The decimals that write ``step`` exactly (to 1e-9 of it): 0 for 5, 1 for 2.5, 2
    for 0.25 (a step of 2.5 written with none had read "0, 2, 5, 8")."""
    dec = max(0, -int(math.floor(math.log10(step) + 1e-9))) if step > 0 else 0
    while dec < 12 and abs(round(step, dec) - step) > 1e-9 * step:
        dec += 1
    return dec


def nice_ticks(lo: float, hi: float, n: int = 5) -> np.ndarray:
    """Round tick values (1, 2, 5 × 10^k steps) inside [lo, hi], about ``n`` of them."""
    if not np.isfinite(lo) or not np.isfinite(hi) or hi <= lo:
        return np.array([lo]) if np.isfinite(lo) else np.array([])
    raw = (hi - lo) / max(n, 1)
    mag = 10 ** math.floor(math.log10(raw))
    step = min((k * mag for k in (1, 2, 2.5, 5, 10)), key=lambda s: abs(s - raw))
    first = math.ceil(lo / step - 1e-9) * step
    return np.arange(first, hi + step * 1e-9, step)


_HOVER = re.compile(r"%\{([^}:]+)(?::([^}]*))?\}")


def _hover_text(template: str | None, fields: dict, i: int) -> str:
    """One marker's hover text from a Plotly ``hovertemplate`` (its %{x:.3f}, %{text},
    %{customdata[0]} ...; ``<extra>`` dropped, ``<br>`` a new line)."""
    if not template:
        parts = [str(fields["text"][i])] if fields.get("text") is not None else []
        return "  ".join(parts + [f"{fields['x'][i]:.4g}, {fields['y'][i]:.4g}"])
    t = re.sub(r"<extra>.*?</extra>", "", template).replace("<br>", "\n")

    def one(m):
        name, spec = m.group(1), m.group(2)
        idx = re.fullmatch(r"(\w+)\[(\d+)\]", name)
        try:
            if idx:
                v = fields[idx.group(1)][i][int(idx.group(2))]
            else:
                src = fields.get(name)
                v = src[i] if src is not None and np.ndim(src) else src
        except (KeyError, IndexError, TypeError):
            return ""
        if spec and isinstance(v, (int, float, np.number)) and np.isfinite(v):
            try:
                return format(float(v), spec)
            except ValueError:
                return str(v)
        return "" if v is None else str(v)

    return re.sub(r"<[^>]+>", "", _HOVER.sub(one, t))


class _Axis:
    """One axis: its pixel span and data range."""

    def __init__(self, name: str, spec, x0: float, x1: float, vertical: bool):
        self.name, self.spec, self.vertical = name, spec, vertical
        self.p0, self.p1 = x0, x1  # pixel span: left->right, or bottom->top for y
        self.lo, self.hi = math.inf, -math.inf
        self.tight = False  # a heatmap's axis: its range is the cells' edges, no padding
        self.log = spec is not None and spec.type == "log"
        self.categories: list | None = None  # a bar chart's category axis, in order

    def category_positions(self, values) -> np.ndarray:
        """Positions 0, 1 ... of category labels on this axis (new ones appended)."""
        if self.categories is None:
            self.categories = []
        out = []
        for v in np.ravel(np.asarray(values, object)):
            if v not in self.categories:
                self.categories.append(v)
            out.append(self.categories.index(v))
        return np.asarray(out, float)

    def take(self, values) -> None:
        v = np.asarray([np.nan if x is None else x for x in np.ravel(values)], float)
        if self.log:
            v = np.log10(np.where(v > 0, v, np.nan))
        v = v[np.isfinite(v)]
        if v.size:
            self.lo, self.hi = min(self.lo, float(v.min())), max(self.hi, float(v.max()))

    def finish(self, pad: float) -> None:
        if self.categories is not None:
            self.lo, self.hi = -0.5, len(self.categories) - 0.5
            return
        spec_range = None if self.spec is None else self.spec.range
        if spec_range is not None and None not in spec_range:
            self.lo, self.hi = float(spec_range[0]), float(spec_range[1])
            return
        if not np.isfinite(self.lo):
            self.lo, self.hi = 0.0, 1.0
        positive = self.lo >= 0
        if self.hi - self.lo < 1e-12 * max(1.0, abs(self.hi)):
            # one value: a tenth of it either side (an RMS of 0.4 µm drawn from -0.6 to
            # 1.4 had read as a negative RMS), one unit for a zero
            half = 0.1 * abs(self.hi) if self.hi != 0 else 1.0
            self.lo, self.hi = self.lo - half, self.hi + half
        d = (self.hi - self.lo) * pad
        self.lo, self.hi = self.lo - d, self.hi + d
        if positive and self.lo < 0 and self.vertical:
            self.lo = 0.0  # values that are never negative get no negative axis (a y axis:
            # an x axis keeps its padding, its first marker not cut at the edge)

    def px(self, v):
        v = np.asarray(v, float)
        if self.log:  # the range of a log axis is in decades, as Plotly's
            v = np.log10(np.where(v > 0, v, np.nan))
        f = (v - self.lo) / (self.hi - self.lo)
        return self.p0 + f * (self.p1 - self.p0)


def _num(values) -> np.ndarray:
    if values is None:
        return np.array([], float)
    return np.asarray([np.nan if x is None else x for x in np.ravel(np.asarray(values,
                                                                               object))], float)


def _path(xs: np.ndarray, ys: np.ndarray, close: bool = False) -> str:
    """An SVG path through the points, broken at missing values."""
    out, pen = [], False
    for x, y in zip(xs, ys, strict=True):
        if not (np.isfinite(x) and np.isfinite(y)):
            pen = False
            continue
        out.append(f"{'L' if pen else 'M'}{x:.1f} {y:.1f}")
        pen = True
    return " ".join(out) + (" Z" if close and out else "")


def _outline(base: str, x: float, y: float, r: float) -> str | None:
    """The path of a closed marker ``base`` (a Plotly symbol name without ``-open`` or
    ``-dot``) of half-size ``r`` px centred on (x, y); None for an unknown name."""
    if base == "square":
        return f"M{x - r:.1f} {y - r:.1f}h{2 * r:.1f}v{2 * r:.1f}h{-2 * r:.1f}Z"
    if base == "diamond":
        d = 1.3 * r
        return f"M{x:.1f} {y - d:.1f}l{d:.1f} {d:.1f}l{-d:.1f} {d:.1f}l{-d:.1f} {-d:.1f}Z"
    if base == "triangle-up":
        d = 1.2 * r
        return f"M{x:.1f} {y - d:.1f}l{d:.1f} {2 * d:.1f}h{-2 * d:.1f}Z"
    return None


def _marker(symbol: str, x: float, y: float, r: float, colour: str, opacity: float) -> str:
    """The opening tag of one marker (the caller adds its ``<title>`` and closes it):
    Plotly's symbol names circle, square, diamond, triangle-up (filled, ``-open``, and with
    a centre dot ``-dot``), x and cross. Shapes it does not know are circles."""
    op = f' opacity="{opacity:g}"' if opacity < 1 else ""
    if symbol in ("x", "cross"):
        d = r * (0.8 if symbol == "x" else 1.0)
        if symbol == "x":
            p = (f"M{x - d:.1f} {y - d:.1f}L{x + d:.1f} {y + d:.1f}"
                 f"M{x - d:.1f} {y + d:.1f}L{x + d:.1f} {y - d:.1f}")
        else:
            p = f"M{x - d:.1f} {y:.1f}H{x + d:.1f}M{x:.1f} {y - d:.1f}V{y + d:.1f}"
        return f'<path d="{p}" stroke="{colour}" stroke-width="2"{op}'
    opened, dotted = "-open" in symbol, "-dot" in symbol
    base = symbol.replace("-open", "").replace("-dot", "")
    paint = (f'fill="none" stroke="{colour}" stroke-width="1.5"' if opened
             else f'fill="{colour}"')
    shape = _outline(base, x, y, r)
    if shape is None and not dotted:
        return f'<circle cx="{x:.1f}" cy="{y:.1f}" r="{r:.1f}" {paint}{op}'
    if shape is None:  # a circle as two arcs, so the dot can be a second sub-path
        shape = (f"M{x - r:.1f} {y:.1f}a{r:.1f} {r:.1f} 0 1 0 {2 * r:.1f} 0"
                 f"a{r:.1f} {r:.1f} 0 1 0 {-2 * r:.1f} 0Z")
    if dotted:
        shape += f"M{x - 0.6:.1f} {y:.1f}h1.2"
    return f'<path d="{shape}" {paint}{op}'


def _dash(dash: str | None) -> str:
    return {"dash": ' stroke-dasharray="6 4"', "dot": ' stroke-dasharray="2 3"',
            "dashdot": ' stroke-dasharray="6 3 2 3"'}.get(dash or "", "")


class _Chart:
    """One figure being drawn: its frame (size, margins), axes and the SVG parts so far."""

    def __init__(self, fig, width_px: int):
        self.fig, lay = fig, fig.layout
        self.lay = lay
        self.H = float(lay.height or 450)
        self.W = float(width_px)
        m = lay.margin
        self.ml = 80 if m.l is None else m.l
        self.mr = 80 if m.r is None else m.r
        self.mt = 100 if m.t is None else m.t
        self.mb = 80 if m.b is None else m.b
        for t in fig.data:  # room for a colour bar right of the plot, as Plotly makes it
            if t.type == "heatmap":
                cb = t.colorbar
                self.mr += ((cb.thickness if cb is not None and cb.thickness else 20)
                            + (cb.xpad if cb is not None and cb.xpad is not None else 10) + 45)
                break
        self.pw = self.W - self.ml - self.mr
        self.ph = self.H - self.mt - self.mb
        self.axes: dict[str, _Axis] = {}
        self.clip_ids: dict = {}
        self.out: list[str] = []
        self.legend: list = []
        self.traces: list[tuple] = []  # (trace, x axis, y axis, x, y)
        self.bars: dict[str, list] = {}  # the bar traces of each x axis: grouped side by side

    def xpaper(self, f):
        return self.ml + f * self.pw

    def ypaper(self, f):
        return self.mt + (1 - f) * self.ph

    def axis(self, ref: str, vertical: bool) -> _Axis:
        """The axis ``ref`` ("x2", "y"), made on first use with its domain."""
        name = ("yaxis" if vertical else "xaxis") + ref[1:]
        if name not in self.axes:
            spec = self.lay[name] if name in self.lay else None
            dom = (spec.domain if spec is not None and spec.domain is not None else (0, 1))
            if vertical:
                self.axes[name] = _Axis(name, spec, self.ypaper(dom[0]), self.ypaper(dom[1]),
                                        True)
            else:
                self.axes[name] = _Axis(name, spec, self.xpaper(dom[0]), self.xpaper(dom[1]),
                                        False)
        return self.axes[name]

    def ranges(self) -> None:
        """Every axis's range from its traces (and shapes), shared axes one range."""
        for t in self.fig.data:
            ax, ay = self.axis(t.xaxis or "x", False), self.axis(t.yaxis or "y", True)
            if t.type == "bar":
                x, y = ax.category_positions(t.x), _num(t.y)
                if not ay.log:
                    ay.take([0.0])
                ay.take(y)
                self.bars.setdefault(t.xaxis or "x", []).append(t)
                self.traces.append((t, ax, ay, x, y))
                continue
            x, y = _num(t.x), _num(t.y)
            if t.type == "heatmap":
                ax.tight = ay.tight = True
                ax.take(_edges(x))
                ay.take(_edges(y))
                self.traces.append((t, ax, ay, x, y))
                continue
            if t.error_y is not None and t.error_y.array is not None:
                e = _num(t.error_y.array)
                ay.take(y + e)
                ay.take(y - e)
            ax.take(x)
            ay.take(y)
            self.traces.append((t, ax, ay, x, y))
        for s in self.lay.shapes or ():  # a data-referenced edge widens the range
            if s.xref and s.xref.startswith("x") and "domain" not in s.xref:
                self.axis(s.xref, False).take([s.x0, s.x1])
            if s.yref and s.yref.startswith("y") and "domain" not in s.yref:
                self.axis(s.yref, True).take([s.y0, s.y1])
        for a in list(self.axes.values()):
            a.finish(0.0 if a.tight else 0.06 if a.vertical else 0.03)
        self.equal_scales()
        groups: dict[str, list[_Axis]] = {}
        for a in self.axes.values():
            match = None if a.spec is None else a.spec.matches
            root = ("yaxis" if a.vertical else "xaxis") + match[1:] if match else a.name
            groups.setdefault(root, []).append(a)
        for group in groups.values():
            lo, hi = min(a.lo for a in group), max(a.hi for a in group)
            for a in group:
                a.lo, a.hi = lo, hi

    def equal_scales(self) -> None:
        """``scaleanchor``: one mm the same length on both axes, the plot area shrunk
        (toward ``constraintoward`` on x, centred on y) rather than the range padded."""
        for ay in [a for a in self.axes.values() if a.vertical]:
            if ay.spec is None or not ay.spec.scaleanchor:
                continue
            ax = self.axes.get("xaxis" + ay.spec.scaleanchor[1:])
            if ax is None:
                continue
            sx = (ax.p1 - ax.p0) / (ax.hi - ax.lo)
            sy = (ay.p0 - ay.p1) / (ay.hi - ay.lo) / (ay.spec.scaleratio or 1)
            k = min(sx, sy)
            if sx > k:
                w = k * (ax.hi - ax.lo)
                if ax.spec is not None and ax.spec.constraintoward == "right":
                    ax.p0 = ax.p1 - w
                elif ax.spec is not None and ax.spec.constraintoward == "left":
                    ax.p1 = ax.p0 + w
                else:
                    mid = (ax.p0 + ax.p1) / 2
                    ax.p0, ax.p1 = mid - w / 2, mid + w / 2
            if sy > k:
                h = k * (ay.hi - ay.lo) * (ay.spec.scaleratio or 1)
                mid = (ay.p0 + ay.p1) / 2
                ay.p0, ay.p1 = mid + h / 2, mid - h / 2

    def heatmap(self, t, ax: _Axis, ay: _Axis, x, y) -> None:
        """The cells of a heatmap, a hover title each, and its colour bar right of it."""
        z = np.asarray(t.z, float)
        lo, hi = _z_limits(t, z)
        xe, ye = ax.px(_edges(x)), ay.px(_edges(y))
        cols = _colours(t, ((z - lo) / (hi - lo)).ravel())
        clip = self.clip_ids.get((t.xaxis or "x", t.yaxis or "y"))
        g = [f'<g clip-path="url(#{clip})">' if clip else "<g>"]
        for i in range(z.shape[0]):
            for j in range(z.shape[1]):
                if not np.isfinite(z[i, j]):
                    continue
                x0, x1 = sorted((xe[j], xe[j + 1]))
                y0, y1 = sorted((ye[i], ye[i + 1]))
                tip = _hover_text(t.hovertemplate, {"x": [x[j]], "y": [y[i]], "z": [z[i, j]]},
                                  0) if t.hovertemplate else f"{z[i, j]:.3g}"
                g.append(f'<rect x="{x0:.1f}" y="{y0:.1f}" width="{x1 - x0 + 0.4:.1f}" '
                         f'height="{y1 - y0 + 0.4:.1f}" fill="{cols[i * z.shape[1] + j]}">'
                         f"<title>{html.escape(tip)}</title></rect>")
        g.append("</g>")
        self.out.extend(g)
        # the colour bar: beside the map, its length a share of the map's height
        cb = t.colorbar
        thick = cb.thickness if cb is not None and cb.thickness else 20
        pad = cb.xpad if cb is not None and cb.xpad is not None else 10
        share = cb.len if cb is not None and cb.len else 1.0
        x0 = ax.p1 + pad
        top = (ay.p1 + ay.p0) / 2 - share * (ay.p0 - ay.p1) / 2
        h = share * (ay.p0 - ay.p1)
        gid = f"cmm-grad-{next(_CLIP_IDS)}"
        stops = "".join(f'<stop offset="{f:.2f}" stop-color="{c}"/>' for f, c in zip(
            np.linspace(0, 1, 11), _colours(t, np.linspace(1, 0, 11)), strict=True))
        self.out.append(f'<defs><linearGradient id="{gid}" x1="0" y1="0" x2="0" y2="1">'
                        f"{stops}</linearGradient></defs>"
                        f'<rect x="{x0:.1f}" y="{top:.1f}" width="{thick}" height="{h:.1f}" '
                        f'fill="url(#{gid})"/>')
        ticks = nice_ticks(lo, hi, 5)
        step = ticks[1] - ticks[0] if len(ticks) > 1 else 1.0
        for v in ticks:
            yy = top + h * (hi - v) / (hi - lo)
            self.out.append(f'<text x="{x0 + thick + 4:.1f}" y="{yy + 4:.1f}" fill="#444">'
                            f"{html.escape(tick_label(float(v), step))}</text>")
        title = cb.title.text if cb is not None and cb.title is not None else None
        if title:
            self.out.append(f'<text x="{x0:.1f}" y="{top - 8:.1f}" fill="#444">'
                            f"{html.escape(title)}</text>")

    def clips(self) -> None:
        """A clip rectangle per subplot: lines and bands stay inside their axes."""
        pairs = {(t.xaxis or "x", t.yaxis or "y") for t, *_ in self.traces}
        for s in self.lay.shapes or ():
            if s.xref and s.yref:
                pairs.add((s.xref.split()[0], s.yref.split()[0]))
        for xr, yr in sorted(pairs):
            ax, ay = self.axis(xr, False), self.axis(yr, True)
            cid = f"cmm-clip-{next(_CLIP_IDS)}"
            self.clip_ids[(xr, yr)] = cid
            self.out.append(f'<clipPath id="{cid}"><rect x="{ax.p0:.1f}" y="{ay.p1:.1f}" '
                            f'width="{ax.p1 - ax.p0:.1f}" height="{ay.p0 - ay.p1:.1f}"/>'
                            "</clipPath>")

    def ticks(self, a: _Axis) -> tuple[list, list]:
        spec = a.spec
        if a.categories is not None:
            return list(range(len(a.categories))), [str(c) for c in a.categories]
        if a.log:
            ks = range(math.ceil(a.lo - 1e-9), math.floor(a.hi + 1e-9) + 1)
            return [10.0 ** k for k in ks], [f"{10.0 ** k:g}" for k in ks]
        if spec is not None and spec.tickmode == "array" and spec.tickvals is not None:
            return ([float(v) for v in spec.tickvals],
                    [str(v) for v in (spec.ticktext or spec.tickvals)])
        n = max(2, int(abs(a.p1 - a.p0) / (50 if a.vertical else 90)))
        ticks = list(nice_ticks(a.lo, a.hi, n))
        step = ticks[1] - ticks[0] if len(ticks) > 1 else 1.0
        return ticks, [tick_label(v, step) for v in ticks]

    def y_axis(self, a: _Axis) -> None:
        spec, out = a.spec, self.out
        anchor = (None if spec is None else spec.anchor) or "x"
        ox = self.axes.get("xaxis" + anchor[1:])
        xs = (ox.p0, ox.p1) if ox is not None else (self.ml, self.W - self.mr)
        show = spec is None or spec.showticklabels is not False
        for v, lab in zip(*self.ticks(a), strict=True):
            yy = float(a.px(v))
            if not a.p1 - 0.5 <= yy <= a.p0 + 0.5:
                continue
            out.append(f'<line x1="{xs[0]:.1f}" x2="{xs[1]:.1f}" y1="{yy:.1f}" '
                       f'y2="{yy:.1f}" stroke="#ebf0f8"/>')
            if show:
                out.append(f'<text x="{xs[0] - 5:.1f}" y="{yy + 4:.1f}" '
                           f'text-anchor="end" fill="#444">{html.escape(lab)}</text>')
        tt = spec.title.text if spec is not None and spec.title is not None else None
        if tt:
            cx, cy = xs[0] - 45, (a.p0 + a.p1) / 2
            out.append(f'<text x="{cx:.1f}" y="{cy:.1f}" text-anchor="middle" '
                       f'transform="rotate(-90 {cx:.1f} {cy:.1f})" fill="#444">'
                       f"{html.escape(tt)}</text>")

    def x_axis(self, a: _Axis) -> None:
        spec, out = a.spec, self.out
        anchor = (None if spec is None else spec.anchor) or "y"
        oy = self.axes.get("yaxis" + anchor[1:])
        ys = (oy.p0, oy.p1) if oy is not None else (self.H - self.mb, self.mt)
        show = spec is None or spec.showticklabels is not False
        angle = spec.tickangle if spec is not None and spec.tickangle else 0
        for v, lab in zip(*self.ticks(a), strict=True):
            xx = float(a.px(v))
            if not a.p0 - 0.5 <= xx <= a.p1 + 0.5:
                continue
            out.append(f'<line x1="{xx:.1f}" x2="{xx:.1f}" y1="{ys[0]:.1f}" '
                       f'y2="{ys[1]:.1f}" stroke="#ebf0f8"/>')
            if not show:
                continue
            if angle:
                out.append(f'<text x="{xx:.1f}" y="{ys[0] + 14:.1f}" text-anchor="end" '
                           f'fill="#444" transform="rotate({angle} {xx:.1f} '
                           f'{ys[0] + 14:.1f})">{html.escape(lab)}</text>')
            else:
                out.append(f'<text x="{xx:.1f}" y="{ys[0] + 16:.1f}" text-anchor="middle" '
                           f'fill="#444">{html.escape(lab)}</text>')
        tt = spec.title.text if spec is not None and spec.title is not None else None
        if tt:
            out.append(f'<text x="{(a.p0 + a.p1) / 2:.1f}" y="{ys[0] + 36:.1f}" '
                       f'text-anchor="middle" fill="#444">{html.escape(tt)}</text>')

    def shapes(self) -> None:
        """Rectangles below the traces (the measured span of each error function)."""
        for s in self.lay.shapes or ():
            if s.type != "rect" or not s.xref or not s.yref:
                continue
            ax, ay = self.axis(s.xref.split()[0], False), self.axis(s.yref.split()[0], True)
            x0, x1 = (ax.px(s.x0), ax.px(s.x1)) if "domain" not in s.xref else (
                ax.p0 + s.x0 * (ax.p1 - ax.p0), ax.p0 + s.x1 * (ax.p1 - ax.p0))
            y0, y1 = (ay.p0 + s.y0 * (ay.p1 - ay.p0), ay.p0 + s.y1 * (ay.p1 - ay.p0)) if (
                "domain" in s.yref) else (ay.px(s.y0), ay.px(s.y1))
            x0, x1 = sorted((float(x0), float(x1)))
            y0, y1 = sorted((float(y0), float(y1)))
            # an outline (a line colour, no fill) is a frame such as the working volume
            outlined = s.line is not None and s.line.color is not None and s.line.width != 0
            fill = s.fillcolor or ("none" if outlined else "rgba(0,0,0,0.1)")
            stroke = (f' stroke="{s.line.color}" stroke-width="{s.line.width or 1:g}"'
                      f"{_dash(s.line.dash)}" if outlined else "")
            tip = (f"<title>{html.escape(s.name)}</title></rect>" if s.name else None)
            self.out.append(f'<rect x="{x0:.1f}" y="{y0:.1f}" width="{x1 - x0:.1f}" '
                            f'height="{y1 - y0:.1f}" fill="{fill}"{stroke}'
                            + (f">{tip}" if tip else "/>"))

    def markers(self, t, px_, py_, x, y, colour) -> list[str]:
        mk = t.marker
        size = mk.size if mk is not None and isinstance(mk.size, (int, float)) else 6
        sym = mk.symbol if mk is not None and isinstance(mk.symbol, str) else "circle"
        op = mk.opacity if mk is not None and isinstance(mk.opacity, (int, float)) else 1.0
        fields = {"x": x, "y": y, "text": None if t.text is None else np.ravel(
            np.asarray(t.text, object)), "customdata": None if t.customdata is None
            else np.asarray(t.customdata, object)}
        err = (_num(t.error_y.array) if t.error_y is not None and t.error_y.array is not None
               else None)
        g = []
        for j in range(len(x)):
            if not (np.isfinite(px_[j]) and np.isfinite(py_[j])):
                continue
            if err is not None and np.isfinite(err[j]):
                ay = next(a for tt, _ax, a, *_ in self.traces if tt is t)
                y_a, y_b = ay.px(y[j] + err[j]), ay.px(y[j] - err[j])
                g.append(f'<line x1="{px_[j]:.1f}" x2="{px_[j]:.1f}" y1="{y_a:.1f}" '
                         f'y2="{y_b:.1f}" stroke="{colour}"/>')
            el = _marker(sym, px_[j], py_[j], size / 2, colour, op)
            if t.hoverinfo != "skip":
                tip = _hover_text(t.hovertemplate, fields, j)
                g.append(f"{el}><title>{html.escape(tip)}</title></{el.split()[0][1:]}>")
            else:
                g.append(el + "/>")
        return g

    def bar(self, i: int, t, ax: _Axis, ay: _Axis, x, y) -> None:
        """Grouped bars: the bars of an x axis side by side in 80 % of each category."""
        group = self.bars[t.xaxis or "x"]
        k, n = group.index(t), len(group)
        colour = (t.marker.color if t.marker is not None and isinstance(t.marker.color, str)
                  else COLORWAY[i % len(COLORWAY)])
        w = 0.8 / n
        base = ay.p0 if ay.log else float(ay.px(0.0))
        texts = None if t.text is None else list(np.ravel(np.asarray(t.text, object)))
        g = []
        for j in range(len(x)):
            if not np.isfinite(y[j]) or (ay.log and y[j] <= 0):
                continue
            left, right = ax.px(x[j] - 0.4 + k * w), ax.px(x[j] - 0.4 + (k + 1) * w)
            top = float(ay.px(y[j]))
            y0, y1 = sorted((top, base))
            g.append(f'<rect x="{left:.1f}" y="{y0:.1f}" width="{right - left:.1f}" '
                     f'height="{y1 - y0:.1f}" fill="{colour}"><title>'
                     f"{html.escape(f'{t.name}: {y[j]:.3g}')}</title></rect>")
            if texts is not None and texts[j]:
                g.append(f'<text x="{(left + right) / 2:.1f}" y="{y0 - 3:.1f}" '
                         f'text-anchor="middle" font-size="10">{html.escape(str(texts[j]))}'
                         "</text>")
        self.out.extend(g)
        if t.showlegend is not False and t.name:
            self.legend.append((t.name, colour, "band", colour, None, "circle"))

    def trace(self, i: int, t, ax: _Axis, ay: _Axis, x, y) -> None:
        if t.type == "heatmap":
            self.heatmap(t, ax, ay, x, y)
            return
        if t.type == "bar":
            self.bar(i, t, ax, ay, x, y)
            return
        default = COLORWAY[i % len(COLORWAY)]
        line_colour = t.line.color if t.line is not None and t.line.color else default
        mk = t.marker
        mcol = mk.color if mk is not None and isinstance(mk.color, str) else line_colour
        mode = t.mode or ("lines+markers" if len(x) < 20 else "lines")
        clip = self.clip_ids.get((t.xaxis or "x", t.yaxis or "y"))
        g = [f'<g clip-path="url(#{clip})">' if clip else "<g>"]
        px_, py_ = ax.px(x), ay.px(y)
        if t.fill == "toself":
            g.append(f'<path d="{_path(px_, py_, close=True)}" '
                     f'fill="{t.fillcolor or "#ccc"}" stroke="none"/>')
        width = t.line.width if t.line is not None and t.line.width is not None else 2
        if "lines" in mode and width > 0 and t.fill != "toself":
            tip = f"<title>{html.escape(str(t.name))}</title>" if t.name else ""
            g.append(f'<path d="{_path(px_, py_)}" fill="none" stroke="{line_colour}" '
                     f'stroke-width="{width:g}"{_dash(t.line.dash if t.line else None)}>'
                     f"{tip}</path>")
        if "markers" in mode:
            g.extend(self.markers(t, px_, py_, x, y, mcol))
        if "text" in mode and t.text is not None:
            for j, lab in enumerate(np.ravel(np.asarray(t.text, object))):
                if lab and np.isfinite(px_[j]) and np.isfinite(py_[j]):
                    g.append(f'<text x="{px_[j] + 6:.1f}" y="{py_[j] + 4:.1f}">'
                             f"{html.escape(str(lab))}</text>")
        g.append("</g>")
        self.out.extend(g)
        shown = t.showlegend or (t.showlegend is None and len(self.fig.data) > 1
                                 and t.legendgroup is None)
        if shown and t.name:
            sym = mk.symbol if mk is not None and isinstance(mk.symbol, str) else "circle"
            self.legend.append((t.name, mcol if "markers" in mode else line_colour,
                                "band" if t.fill == "toself" else mode, t.fillcolor,
                                t.line.dash if t.line else None, sym))

    def _ref(self, ref: str, v: float, vertical: bool) -> float:
        if ref == "paper":
            return self.ypaper(v) if vertical else self.xpaper(v)
        a = self.axis(ref.split()[0], vertical)
        if "domain" in ref:
            return a.p0 + v * (a.p1 - a.p0)
        return float(a.px(v))

    def annotations(self) -> None:
        """Subplot titles (paper) and notes in an axis's domain."""
        for a in self.lay.annotations or ():
            if not a.text:
                continue
            xx = self._ref(a.xref or "paper", a.x, False)
            yy = self._ref(a.yref or "paper", a.y, True) - (4 if a.yanchor == "bottom" else 0)
            anchor = {"left": "start", "right": "end"}.get(a.xanchor or "center", "middle")
            size = a.font.size if a.font is not None and a.font.size else 14
            text = re.sub(r"<[^>]+>", "", str(a.text))
            self.out.append(f'<text x="{xx:.1f}" y="{yy:.1f}" text-anchor="{anchor}" '
                            f'font-size="{size}">{html.escape(text)}</text>')

    def legend_rows(self) -> float:
        """The legend as rows under the figure; returns the figure's full height."""
        if not self.legend:
            return self.H
        x0, y0, rows, out = self.ml, self.H + 4, 1, self.out
        for name, colour, kind, fill, dash, sym in self.legend:
            wtext = 7 * len(name) + 34
            if x0 + wtext > self.W - 10:
                rows += 1
                x0, y0 = self.ml, y0 + _LEGEND_ROW_PX
            if kind == "band":
                out.append(f'<rect x="{x0:.0f}" y="{y0 + 4:.0f}" width="20" height="10" '
                           f'fill="{fill or "#ccc"}"/>')
            elif "markers" in kind:
                out.append(_marker(sym, x0 + 10, y0 + 9, 4, colour, 1.0) + "/>")
            else:
                out.append(f'<line x1="{x0:.0f}" x2="{x0 + 20:.0f}" y1="{y0 + 9:.0f}" '
                           f'y2="{y0 + 9:.0f}" stroke="{colour}" stroke-width="2"'
                           f"{_dash(dash)}/>")
            out.append(f'<text x="{x0 + 26:.0f}" y="{y0 + 13:.0f}">{html.escape(name)}'
                       "</text>")
            x0 += wtext
        return self.H + 8 + rows * _LEGEND_ROW_PX


def placement_views_svg(dataset: Dataset, *, width_px: int = 1100) -> str:
    """The plate placements in three views of the machine volume
    (:func:`~cmm_core.analysis.figures.fig_placement_views`) as SVG: hover a marker for
    its placement, stylus, ball and coordinates."""
    return figure_svg(fig_placement_views(dataset), width_px)


def figure_svg(fig, width_px: int = 1100) -> str:
    """``fig`` (a Plotly figure of 2-D traces, :func:`svg_supported`) as one SVG
    element, ``width_px`` wide in its own units and scaled to the width of its container."""
    c = _Chart(fig, width_px)
    c.ranges()
    title = c.lay.title.text if c.lay.title is not None else None
    if title:
        c.out.append(f'<text x="{c.ml:.0f}" y="{min(30, c.mt - 12):.0f}" font-size="16">'
                     f"{html.escape(str(title))}</text>")
    c.clips()
    for a in list(c.axes.values()):
        (c.y_axis if a.vertical else c.x_axis)(a)
    c.shapes()
    for i, (t, ax, ay, x, y) in enumerate(c.traces):
        c.trace(i, t, ax, ay, x, y)
    c.annotations()
    height = c.legend_rows()
    head = (f'<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {c.W:.0f} {height:.0f}" '
            f'width="100%" style="height:auto" {_FONT} font-size="12" '
            'role="img">')
    return "\n".join([head, *c.out, "</svg>"])
