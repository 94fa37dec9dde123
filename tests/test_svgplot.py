"""The app's static SVG figures (cmm_core.analysis.svg, issue 27): every marker, cell and bar
where its data put it, on the scale its axes state. Checked on the SVG's own coordinates
(0.1 px rounding), with random data from a seeded generator."""

import re

import numpy as np
import plotly.graph_objects as go
import pytest
from plotly.subplots import make_subplots

from cmm_core.analysis import figure_svg, nice_ticks, tick_label
from cmm_core.analysis import svg_supported as supported

CIRCLE = re.compile(r'<circle cx="(-?[\d.]+)" cy="(-?[\d.]+)" r="[\d.]+" fill="[^"]+"[^>]*>'
                    r"<title>([^<]*)</title>")


def _affine(u, p):
    """Least-squares line p = a u + b and its largest residual (px)."""
    a, b = np.polyfit(u, p, 1)
    return a, np.abs(np.polyval([a, b], u) - p).max()


def test_markers_sit_at_their_data_on_one_scale_per_axis_y_up(rng):
    x, y = rng.uniform(-50, 200, 40), rng.normal(0, 3, 40)
    fig = go.Figure(go.Scatter(x=x, y=y, mode="markers", text=[f"p{i}" for i in range(40)],
                               hovertemplate="%{text}: %{y:.3f} µm<extra></extra>"))
    svg = figure_svg(fig, 800)
    got = CIRCLE.findall(svg)
    assert len(got) == 40
    cx, cy = (np.array([float(g[k]) for g in got]) for k in (0, 1))
    ax, rx = _affine(x, cx)
    ay, ry = _affine(y, cy)
    assert ax > 0 and ay < 0  # right and up
    assert rx < 0.1 and ry < 0.1  # the coordinates are written to 0.1 px
    # the hover title is the trace's hovertemplate, filled in per marker
    assert [g[2] for g in got] == [f"p{i}: {v:.3f} µm" for i, v in enumerate(y)]


def test_shared_y_axes_put_one_value_at_one_height(rng):
    fig = make_subplots(rows=1, cols=2, shared_yaxes=True)
    fig.add_trace(go.Scatter(x=[0, 1, 2], y=[0.0, 5.0, 10.0], mode="markers"), row=1, col=1)
    fig.add_trace(go.Scatter(x=[0, 1], y=[-20.0, 5.0], mode="markers"), row=1, col=2)
    got = CIRCLE.findall(figure_svg(fig, 900))
    heights = {float(g[1]) for g in got if g[2].endswith(", 5")}
    assert len(heights) == 1  # y = 5 at the same height in both panels
    left = [float(g[0]) for g in got[:3]]
    right = [float(g[0]) for g in got[3:]]
    assert max(left) < min(right)  # each panel in its own domain


def test_bars_on_a_log_axis_reach_the_log_of_their_value():
    vals = [0.02, 0.5, 3.0, 40.0]
    fig = go.Figure(go.Bar(x=list("abcd"), y=vals, name="limits"))
    fig.update_yaxes(type="log", range=[np.log10(0.01), np.log10(100)])
    svg = figure_svg(fig, 600)
    bars = re.findall(r'<rect x="(-?[\d.]+)" y="(-?[\d.]+)" width="([\d.]+)" '
                      r'height="([\d.]+)" fill="[^"]+"><title>limits', svg)
    assert len(bars) == 4
    tops = np.array([float(b[1]) for b in bars])
    bottoms = tops + np.array([float(b[3]) for b in bars])
    a, res = _affine(np.log10(vals), tops)
    assert a < 0 and res < 0.2  # top edge linear in log10(value)
    assert np.ptp(bottoms) < 0.2  # all from the axis floor
    # the category labels and the decades as ticks
    for t in ("a", "b", "c", "d", "0.01", "0.1", "1", "10", "100"):
        assert f">{t}</text>" in svg


def test_heatmap_cells_take_their_colour_from_the_scale_and_carry_their_value():
    z = np.array([[-1.0, 0.0], [0.5, 1.0]])
    fig = go.Figure(go.Heatmap(x=[0, 10], y=[0, 20], z=z, colorscale="RdBu_r", zmid=0.0,
                               hovertemplate="%{x:.0f}, %{y:.0f}: %{z:.2f}<extra></extra>"))
    svg = figure_svg(fig, 500)
    cells = re.findall(r'fill="(rgb\([^)]+\))"><title>([^<]*)</title>', svg)
    assert [c[1] for c in cells] == ["0, 0: -1.00", "10, 0: 0.00", "0, 20: 0.50",
                                     "10, 20: 1.00"]
    colour = dict((c[1], c[0]) for c in cells)
    assert colour["0, 0: -1.00"] == "rgb(5, 48, 97)"  # RdBu_r's ends and middle
    assert colour["10, 20: 1.00"] == "rgb(103, 0, 31)"
    assert colour["10, 0: 0.00"] == "rgb(247, 247, 247)"
    assert 'fill="url(#cmm-grad-' in svg  # the colour bar


def test_only_2d_scatter_heatmap_and_bars_are_drawn():
    assert supported(go.Figure([go.Scatter(x=[1], y=[1]), go.Bar(x=["a"], y=[1])]))
    assert not supported(go.Figure(go.Scatter3d(x=[1], y=[1], z=[1])))


@pytest.mark.parametrize(("lo", "hi"), [(0.0, 1.0), (-47.3, 52.1), (1e-3, 4e-3), (0, 1200)])
def test_ticks_are_round_and_inside(lo, hi):
    t = nice_ticks(lo, hi, 5)
    assert 3 <= len(t) <= 11
    assert t.min() >= lo - 1e-12 and t.max() <= hi + 1e-12
    step = np.diff(t)
    assert np.allclose(step, step[0])
    mant = step[0] / 10 ** np.floor(np.log10(step[0]))
    assert any(np.isclose(mant, m) for m in (1, 2, 2.5, 5))


@pytest.mark.parametrize(("lo", "hi", "n"), [(0, 10, 4), (0, 1.05, 3), (-0.4, 0.9, 5),
                                             (0, 8, 4), (100, 1100, 4), (0, 0.03, 4),
                                             (99990, 100010, 4), (0, 3e-4, 5),
                                             (-3e-4, 0, 5), (0, 1.2e6, 4), (0, 2.6e6, 5)])
def test_every_tick_label_reads_its_value(lo, hi, n):
    """Issue 41: a 2.5 step had been labelled "0, 2, 5, 8"; each label now parses back to
    its tick to within a millionth of the step, and no two labels are the same."""
    t = nice_ticks(lo, hi, n)
    step = t[1] - t[0]
    labels = [tick_label(float(v), step) for v in t]
    assert len(set(labels)) == len(labels)
    for v, lab in zip(t, labels, strict=True):
        assert float(lab.replace("−", "-")) == pytest.approx(v, abs=1e-6 * step)


def test_a_single_positive_value_gets_no_negative_axis():
    """One history step (RMS 0.4 µm): the y axis had run from −0.6 µm."""
    svg = figure_svg(go.Figure(go.Scatter(x=[0], y=[0.4], mode="markers")))
    ys = [float(m.replace("−", "-")) for m in re.findall(r'text-anchor="end"[^>]*>([^<]+)<', svg)]
    assert ys and min(ys) >= 0 and max(ys) >= 0.4


HOSTILE = '<script>alert("x")</script><img src=x onerror=alert(1)>'


def test_text_from_the_data_is_escaped_everywhere_it_is_written():
    """The app frames each SVG as its own document, where a script would run (issue 41):
    a name read from a user's file (a placement, a trace, a title, an axis title, an
    annotation, a hover text) is written as text, never as markup."""
    fig = make_subplots(rows=1, cols=2, subplot_titles=[HOSTILE, "b"])
    fig.add_trace(go.Scatter(x=[0, 1], y=[1, 2], mode="markers", name=HOSTILE,
                             text=[HOSTILE, HOSTILE],
                             hovertemplate="%{text}<extra></extra>"), row=1, col=1)
    fig.add_trace(go.Bar(x=[HOSTILE, "q"], y=[1, 2], name=HOSTILE), row=1, col=2)
    fig.update_layout(title=HOSTILE, showlegend=True)
    fig.update_xaxes(title=HOSTILE)
    fig.add_annotation(text=HOSTILE, x=0.5, y=0.5, xref="paper", yref="paper",
                       showarrow=False)
    svg = figure_svg(fig, 900)
    assert "<script" not in svg and "<img" not in svg
    assert svg.count("&lt;script&gt;") >= 5  # drawn, as text


def test_the_frame_document_escapes_its_key_and_holds_the_svg_whole():
    pytest.importorskip("streamlit")
    from pages.ui.widgets import svg_document

    svg = figure_svg(go.Figure(go.Scatter(x=[0, 1], y=[0, 1], mode="markers")), 600)
    doc = svg_document(svg, 'a"><script>alert(1)</script>')
    assert svg in doc
    assert doc.count("<script") == 1  # the frame's own height script, nothing else
    assert 'data-figure="a&quot;&gt;&lt;script&gt;' in doc
