"""The display helpers the pages share: the χ² banner, the model spec in words, widgets
bound to the state, figures (static SVG or Plotly), tables and maps."""

from __future__ import annotations

import html
import inspect
import re

import streamlit as st

from cmm_core import analysis as A
from cmm_core.analysis import figure_svg, svg_supported
from cmm_core.model import parse_spec
from cmm_core.units import p_text
from pages.ui.cached import figure
from pages.ui.state import spec_tokens


def misfit_banner(r) -> None:
    """Next to any uncertainty: the fit's χ² test, and when it fails, by how much the
    σ-based values understate the observed scatter (Birge ratio)."""
    if r is None:
        return
    val, dof, note = A.chi2_test_numbers(r)
    if r.fails_chi2_test:
        st.warning(f"The model fails its χ² test: χ²/dof {val:.2f} at {dof} degrees "
                   f"of freedom ({p_text(r.chi2_p_value)}){note}. Uncertainties from σ = "
                   f"{r.sigma_um:.3g} µm alone are too small by the Birge ratio "
                   f"×{r.birge_ratio:.2f}; multiply them by it (inflated values are shown "
                   "beside them where listed). Neither is trustworthy until the diagnosis "
                   "explains the misfit.")
    else:
        st.caption(f"χ² test passed: χ²/dof {val:.2f} at {dof} degrees of freedom "
                   f"({p_text(r.chi2_p_value)}){note}; the σ-based uncertainties stand.")


def headline(h: dict, where=None) -> None:
    """The diagnosis's headline (``Headline.to_dict``) as one message of its level
    (``st.success``, ``info``, ``warning``, ``error``): the title in bold, the text, the
    action; in ``where`` (a column or container) when given."""
    draw = getattr(where if where is not None else st, h["level"])
    draw(f"**{h['title']}**\n\n{h['text']}\n\nNext: {h['action']}")


_MD_SPECIAL = re.compile(r"([\\`*_\[\]{}<>#|~$:&])")
# what starts a list where a line starts ("- dxx" is a spec that removes dxx, "1." a name)
_MD_LINE_START = re.compile(r"^(\s*(?:\d+(?=[.)](?:\s|$))|(?=[-+])))([-+.)])")


def md_escape(text) -> str:
    """``text`` as literal markdown: its special characters escaped (a name ``*A|B``,
    ``probe_offset`` or ``A&B`` stays that text, a leading ``- `` or ``1.`` starts no list),
    a line break a blank."""
    text = _MD_SPECIAL.sub(r"\\\1", str(text)).replace("\n", " ")
    return _MD_LINE_START.sub(r"\1\\\2", text)


def spec_text(spec: str) -> str:
    """The spec as written, one blank after each comma: a table cell wraps there rather
    than inside a name (the blank parses the same)."""
    return ", ".join(spec_tokens(spec))


def spec_expansion(spec: str, order: int | None = None) -> str | None:
    """The explicit form of ``spec`` (``ModelSpec.to_string``) when it differs from what was
    written (``translational,squareness`` names nine functions), else None."""
    try:
        full = parse_spec(spec, default_order=int(order or st.session_state.get("order", 2)))
    except ValueError:
        return None
    full = full.to_string()
    return None if spec_tokens(full) == spec_tokens(spec) else full


def spec_markdown(spec: str, order: int | None = None) -> tuple[str, str]:
    """``(markdown, help)`` of the model spec for ``st.markdown(markdown, help=help)``: the
    spec as the user wrote it, one blank after each comma (it wraps there, never inside a
    name), markdown's characters escaped; the help is the spec as one string and, where
    it differs, its expansion into functions. Plain markdown rather than HTML: the
    sidebar draws it on every page, and HTML in markdown (or a ``<code>`` span) makes a
    first load fetch and run the frontend's HTML parser and code font (issue 41)."""
    hover = md_escape(",".join(spec_tokens(spec)))
    full = spec_expansion(spec, order)
    if full:
        hover += f"  \n= {md_escape(full)}"
    return md_escape(spec_text(spec)), hover


def flash():
    """Show the one-off message of the last action in a slot that is always present, so the
    elements below keep their place (a tab set below would otherwise reset)."""
    slot = st.container()
    msg = st.session_state.pop("flash", None)
    if msg:
        getattr(slot, msg[0])(msg[1])


def bind(state_key: str, widget_fn, label: str, **kwargs):
    """A widget (``w_<state_key>``) initialised from and written back to the state."""
    wk = "w_" + state_key
    if wk not in st.session_state:
        st.session_state[wk] = st.session_state[state_key]
    val = widget_fn(label, key=wk, **kwargs)
    st.session_state[state_key] = val
    return val


INTERACTIVE = "interactive_plots"
"""The sidebar switch: the pages' 2-D figures as Plotly charts instead of static SVG."""


def plot(kind: str, key: tuple, builder, *args, chart_key: str, width_px: int = 1100,
         **kwargs):
    """A core figure (``builder(*args)``, cached under ``(kind, key)`` as
    :func:`cached.figure`) drawn as static SVG on the server, or as a Plotly chart when the
    sidebar's "Interactive plots" is on or the figure is not a 2-D scatter (issue 27: a
    Plotly chart costs the browser its 4.7 MB of script once and 0.1-1 s of drawing per
    figure and rerun; the SVG is text the browser lays out at once). ``width_px``: the
    width the SVG is laid out for (it scales to its column); ``kwargs`` go to
    ``st.plotly_chart``. The SVG sits in a container keyed ``chart_key`` (and says so in
    its ``data-figure``), the chart has that key."""
    fig = figure(kind, key, builder, *args)
    if st.session_state.get(INTERACTIVE) or not svg_supported(fig):
        st.plotly_chart(fig, key=chart_key, **kwargs)
        return
    svg_figure(figure(f"{kind}.svg", (key, width_px), figure_svg, fig, width_px),
               chart_key)


def show(fig, *, chart_key: str, width_px: int = 1100, **kwargs):
    """A figure built on this run (not cached): static SVG, or a Plotly chart as in
    :func:`plot`."""
    if st.session_state.get(INTERACTIVE) or not svg_supported(fig):
        st.plotly_chart(fig, key=chart_key, **kwargs)
        return
    svg_figure(figure_svg(fig, width_px), chart_key)


def held(*prefixes: str, text: tuple[str, ...] = (), changed: dict | None = None) -> bool:
    """Whether the fields of a tab drawn only while open hold something the user put
    there (issue 27): a file, list, dict or report under one of ``prefixes``, a text
    typed under one of ``text``, a value under a key starting with one of ``changed``'s
    keys that differs from its default there. Streamlit forgets a widget's value when the
    widget is not drawn, so such a tab stays drawn while another is looked at."""
    s = st.session_state

    def chosen(v) -> bool:
        return len(v) > 0 if isinstance(v, (list, tuple, dict)) else hasattr(v, "getvalue")

    items = [(str(k), v) for k, v in s.items()]
    return (any(chosen(v) for k, v in items if k.startswith(prefixes))
            or any(isinstance(v, str) and v.strip() != "" for k, v in items
                   if k.startswith(text))
            or any(v is not None and v != default for k, v in items
                   for key, default in (changed or {}).items() if k.startswith(key)))


# Streamlit sizes a frame "as tall as its content" by the document's height, which is never
# less than the frame's own: grown with a wider page, it would never shrink with a narrower
# one. The picture's own height is posted on Streamlit's message after Streamlit's
# (setTimeout: its listener runs after this one) at load and on every resize.
_FIT_HEIGHT = """<script>(function () {
  var fig = document.querySelector("[data-figure]");
  function post() {
    var r = fig.getBoundingClientRect();
    parent.postMessage({type: "streamlit:iframe:setSize", width: Math.ceil(r.width),
                        height: Math.ceil(r.height)}, "*");
  }
  function later() { setTimeout(post, 0); }
  addEventListener("load", later);
  addEventListener("resize", later);
})();</script>"""


def svg_document(svg: str, key: str) -> str:
    """The HTML document :func:`svg_figure` frames: ``svg`` in a ``div`` whose
    ``data-figure`` is ``key``, no margin, and the script that keeps the frame as tall as
    the picture when the page's width changes."""
    return ('<!doctype html><html><head><meta charset="utf-8">'
            # no scroll bar: a frame briefly shorter than its picture (a wider page, the
            # first draw) would keep one and lay the picture out narrower under it
            "<style>html,body{margin:0;overflow:hidden}svg{display:block}</style>"
            "</head><body>"
            f'<div data-figure="{html.escape(key, quote=True)}">{svg}</div>'
            f"{_FIT_HEIGHT}</body></html>")


def svg_figure(svg: str, key: str) -> None:
    """An SVG picture (the server's own, from :func:`figure_svg`) on the page, in a
    container keyed ``key``, as its own document in an iframe as tall as its content
    (:func:`svg_document`). Not ``st.markdown``'s HTML: the frontend parses that in script
    and builds an element per node, 0.12 s of a first load for the placements' 1 000
    nodes (issue 41), where the iframe's document is parsed by the browser; not
    ``st.html``, which sanitises SVG away; not ``st.image``, which loses the hover label
    of every marker. A frame's document runs scripts: ``svg`` must be the server's own
    drawing, whose every text from the data is escaped (``figure_svg``; tested with
    markup in trace names, titles, axis titles, annotations, hover texts and bar
    categories)."""
    with st.container(key=key):
        st.iframe(svg_document(svg, key), height="content")


def beside_map(fig):
    """A map (``report.fig_surface_grid``) drawn in a column: the colour bar right beside
    the map (the equal-scale axes shrink the plot area; anchored right, it sits next to
    the bar) and slim."""
    fig.update_traces(colorbar={"thickness": 14, "xpad": 4, "len": 0.9},
                      selector={"type": "heatmap"})
    fig.update_xaxes(constraintoward="right")
    fig.update_layout(margin={"l": 60, "r": 10, "t": 60, "b": 50})
    return fig


_DF_PLACEHOLDER = "placeholder" in inspect.signature(st.dataframe).parameters

def _table_cell(value, float_format: str) -> str:
    """One cell of :func:`static_table`: "—" for a missing value, floats formatted,
    markdown's special characters escaped (a position named ``*A|B`` stays that text)."""
    if value is None or (isinstance(value, float) and value != value):
        return "—"
    if isinstance(value, float):
        return format(value, float_format)
    return md_escape(value)


def static_table_markdown(data, float_format: str = ".1f") -> str:
    """The markdown of :func:`static_table`: a header row, the alignment row (numbers
    right-aligned) and one row per row of ``data``."""
    cols = list(data.columns)
    numeric = [data[c].dtype.kind in "iuf" for c in cols]
    lines = ["| " + " | ".join(_table_cell(str(c), float_format) for c in cols) + " |",
             "|" + "|".join("---:" if n else ":---" for n in numeric) + "|"]
    lines += ["| " + " | ".join(_table_cell(v.item() if hasattr(v, "item") else v,
                                            float_format) for v in row) + " |"
              for row in data.itertuples(index=False, name=None)]
    return "\n".join(lines)


def static_table(data, key: str, float_format: str = ".1f") -> None:
    """A small table as markdown in a container keyed ``key``: for a table on a page's
    first screen that nobody sorts or filters. ``st.dataframe`` and ``st.table`` both
    make the browser load the data grid's and Arrow's scripts (some 1.3 MB) before the
    page is drawn, which a first load pays (issue 27); markdown is drawn by the script
    every page already has. Missing values read "—", floats ``float_format``."""
    with st.container(key=key):
        st.markdown(static_table_markdown(data, float_format))


def dataframe(data, **kwargs):
    """``st.dataframe`` showing missing values as "—" rather than "None" (a metrologist
    reads "None" as a value), where this Streamlit has the ``placeholder`` option."""
    if _DF_PLACEHOLDER:
        kwargs.setdefault("placeholder", "—")
    return st.dataframe(data, **kwargs)
