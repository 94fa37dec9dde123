"""Figures as plain SVG text: drawn by the browser at once, without Plotly's script.

Plotly's browser bundle is the largest part of the app's first load (4.7 MB of the 10.5 MB
of script a first visit fetches and compiles, issue 27). The first screen of the app (the
Data page) therefore draws its one figure, the placements in the machine volume, as SVG;
each marker carries a ``<title>``, so hovering shows the placement, stylus, ball and
coordinates as Plotly's tooltip did. The interactive figures stay Plotly.
"""

from __future__ import annotations

import html
import math

import numpy as np

from ..io import Dataset

__all__ = ["placement_views_svg"]

_PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
           "#7f7f7f", "#bcbd22", "#17becf")
"""Placement colours, in the order of the placements (Plotly's default sequence)."""

_SYMBOLS = ("circle", "square", "diamond", "triangle", "x", "plus", "circle-dot",
            "square-x")
_VIEWS = (("XY (top)", 0, 1), ("XZ (front)", 0, 2), ("YZ (side)", 1, 2))


def _nice_ticks(lo: float, hi: float, most: int = 6) -> np.ndarray:
    """Round tick values covering ``[lo, hi]``: a step of 1, 2 or 5 × 10^k giving at
    most ``most`` ticks."""
    span = max(hi - lo, 1e-9)
    for step in (m * 10.0 ** e for e in range(math.floor(math.log10(span / most)) - 1, 12)
                 for m in (1.0, 2.0, 5.0)):
        first = math.ceil(lo / step) * step
        ticks = np.arange(first, hi + step * 1e-9, step)
        if len(ticks) <= most:
            return ticks
    return np.array([lo, hi])  # pragma: no cover - a span beyond 10^12 mm


def _marker(kind: str, x: float, y: float, colour: str, tip: str) -> str:
    """One open marker of ``kind`` at (x, y) px, its ``<title>`` the hover text."""
    r = 3.5
    shapes = {
        "circle": f'<circle cx="{x:.1f}" cy="{y:.1f}" r="{r}"/>',
        "square": f'<rect x="{x - r:.1f}" y="{y - r:.1f}" width="{2 * r}" height="{2 * r}"/>',
        "diamond": f'<path d="M{x:.1f},{y - r - 1:.1f}l{r + 1},{r + 1}l{-r - 1},{r + 1}'
                   f'l{-r - 1},{-r - 1}z"/>',
        "triangle": f'<path d="M{x:.1f},{y - r - 1:.1f}l{r + 1},{2 * r + 1}h{-2 * r - 2}z"/>',
        "x": f'<path d="M{x - r:.1f},{y - r:.1f}l{2 * r},{2 * r}m0,{-2 * r}l{-2 * r},{2 * r}"/>',
        "plus": f'<path d="M{x - r:.1f},{y:.1f}h{2 * r}m{-r},{-r}v{2 * r}"/>',
        "circle-dot": f'<circle cx="{x:.1f}" cy="{y:.1f}" r="{r}"/>'
                      f'<circle cx="{x:.1f}" cy="{y:.1f}" r="0.6"/>',
        "square-x": f'<rect x="{x - r:.1f}" y="{y - r:.1f}" width="{2 * r}" height="{2 * r}"/>'
                    f'<path d="M{x - r:.1f},{y - r:.1f}l{2 * r},{2 * r}"/>',
    }
    return (f'<g fill="none" stroke="{colour}" stroke-width="1.3">'
            f"<title>{html.escape(tip)}</title>{shapes[kind]}</g>")


def placement_views_svg(dataset: Dataset, *, height_px: int = 330) -> str:
    """The plate placements in three orthographic views of the machine volume (top XY,
    front XZ, side YZ; mm) as one SVG: the working volume's outline, every probed ball
    centre (the tip centre in the machine frame) with one colour and symbol per placement, equal scales on both axes of a view, and a
    legend. Hover a marker for its placement, stylus, ball and coordinates."""
    rng = np.asarray(dataset.setup.range_mm, float)
    m = dataset.meas
    xyz = m[["mx_mm", "my_mm", "mz_mm"]].to_numpy(float)
    pad_mm = 0.06 * rng.max()
    plot_h = height_px - 90.0  # title, axis labels and tick labels
    parts, x0 = [], 55.0
    for title, i, j in _VIEWS:
        lo = np.minimum([0.0, 0.0], [xyz[:, i].min(), xyz[:, j].min()]) - pad_mm
        hi = np.maximum([rng[i], rng[j]], [xyz[:, i].max(), xyz[:, j].max()]) + pad_mm
        scale = plot_h / (hi[1] - lo[1])  # px per mm, the same on both axes
        w = (hi[0] - lo[0]) * scale

        def px(a, b, lo=lo, scale=scale, x0=x0):
            return x0 + (a - lo[0]) * scale, 30.0 + plot_h - (b - lo[1]) * scale

        g = [f'<text x="{x0 + w / 2:.1f}" y="18" text-anchor="middle" '
             f'font-weight="600">{title}</text>',
             f'<rect x="{x0:.1f}" y="30" width="{w:.1f}" height="{plot_h:.1f}" fill="#fafafa" '
             'stroke="#ccc"/>']
        a0, b0 = px(0.0, 0.0)
        a1, b1 = px(rng[i], rng[j])
        g.append(f'<rect x="{a0:.1f}" y="{b1:.1f}" width="{a1 - a0:.1f}" height="{b0 - b1:.1f}" '
                 'fill="none" stroke="grey" stroke-dasharray="4 3"><title>working volume '
                 f'{rng[i]:g} × {rng[j]:g} mm</title></rect>')
        for t in _nice_ticks(lo[0], hi[0], 5):
            tx, _ = px(t, lo[1])
            g.append(f'<text x="{tx:.1f}" y="{30 + plot_h + 14:.1f}" text-anchor="middle" '
                     f'font-size="10">{t:g}</text>')
        for t in _nice_ticks(lo[1], hi[1], 6):
            _, ty = px(lo[0], t)
            g.append(f'<text x="{x0 - 4:.1f}" y="{ty + 3:.1f}" text-anchor="end" '
                     f'font-size="10">{t:g}</text>')
        ax, bx = "XYZ"[i], "XYZ"[j]
        g.append(f'<text x="{x0 + w / 2:.1f}" y="{30 + plot_h + 30:.1f}" '
                 f'text-anchor="middle" font-size="11">{ax} (mm)</text>')
        g.append(f'<text x="{x0 - 40:.1f}" y="{30 + plot_h / 2:.1f}" font-size="11" '
                 f'text-anchor="middle" transform="rotate(-90 {x0 - 40:.1f} '
                 f'{30 + plot_h / 2:.1f})">{bx} (mm)</text>')
        for k, (pos, idx) in enumerate(m.groupby("position", sort=False).indices.items()):
            colour, kind = _PALETTE[k % len(_PALETTE)], _SYMBOLS[k % len(_SYMBOLS)]
            for n in idx:
                cx, cy = px(xyz[n, i], xyz[n, j])
                tip = (f"{pos}, probe {m['probe'].iat[n]}, ball {m['ball'].iat[n]}: "
                       f"{ax} {xyz[n, i]:.1f}, {bx} {xyz[n, j]:.1f} mm")
                g.append(_marker(kind, cx, cy, colour, tip))
        parts.append("".join(g))
        x0 += w + 75.0
    legend, lx = [], 55.0
    for k, pos in enumerate(m["position"].drop_duplicates()):
        colour, kind = _PALETTE[k % len(_PALETTE)], _SYMBOLS[k % len(_SYMBOLS)]
        legend.append(_marker(kind, lx, height_px - 12.0, colour, str(pos))
                      + f'<text x="{lx + 8:.1f}" y="{height_px - 8:.1f}" font-size="11">'
                      f'{html.escape(str(pos))}</text>')
        lx += 18 + 7 * len(str(pos)) + 14
    width = max(x0 - 20.0, lx)
    return (f'<svg xmlns="http://www.w3.org/2000/svg" viewBox="0 0 {width:.0f} {height_px}" '
            f'width="100%" style="max-width:{width:.0f}px;font-family:sans-serif" '
            'role="img" aria-label="Plate placements in the machine volume">'
            + "".join(parts) + "".join(legend) + "</svg>")
