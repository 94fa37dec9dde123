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


def spec_markup(spec: str, order: int | None = None) -> str:
    """HTML (for ``st.markdown(..., unsafe_allow_html=True)``): the spec as the user wrote
    it, breakable after each comma and never inside a name, the full text and its
    expansion on hover."""
    toks = spec_tokens(spec)
    hover = ",".join(toks)
    full = spec_expansion(spec, order)
    if full:
        hover += f"\n= {full}"
    body = ",<wbr>".join(html.escape(t) for t in toks)
    return (f'<code class="cmm-spec" title="{html.escape(hover, quote=True)}" '
            'style="white-space: normal; word-break: normal; overflow-wrap: normal">'
            f"{body}</code>")


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


def svg_figure(svg: str, key: str) -> None:
    """An SVG picture on the page, in a container keyed ``key`` and a ``div`` whose
    ``data-figure`` is ``key``. Through ``st.markdown``'s HTML: ``st.html`` sanitises SVG
    away (Streamlit 1.67 draws an empty element)."""
    with st.container(key=key):
        st.markdown(f'<div data-figure="{key}">{svg}</div>', unsafe_allow_html=True)


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

_MD_SPECIAL = re.compile(r"([\\`*_\[\]{}<>#|~$:])")


def _table_cell(value, float_format: str) -> str:
    """One cell of :func:`static_table`: "—" for a missing value, floats formatted,
    markdown's special characters escaped (a position named ``*A|B`` stays that text)."""
    if value is None or (isinstance(value, float) and value != value):
        return "—"
    if isinstance(value, float):
        return format(value, float_format)
    return _MD_SPECIAL.sub(r"\\\1", str(value)).replace("\n", " ")


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
