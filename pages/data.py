"""Data page: load the thesis tables, upload CSVs or other tools' files, simulate,
restore a project, add instrument files (laser runs, step gauges, ball bars); the dataset's
validation report, outliers and placements."""

import streamlit as st

from cmm_core import analysis as A
from cmm_core import io as cio
from pages.ui import cached, calls, session, state, widgets
from pages.ui.panels import instruments, project, simulate, upload
from pages.ui.panels.msl import msl_section

st.title("Data")
st.caption("Ball-plate measurements, setup and certificate. Files are in mm; the screen "
           "shows µm.")
widgets.flash()

# the first screen says what the loaded data show and the one next step (issue 41)
with calls.guarded("Summary"):
    try:
        _ds = state.dataset()
    except Exception:  # noqa: BLE001 - the validation report below says why
        _ds = None
    if _ds is not None:
        look = A.first_look(_ds, cached.current_fit(show_error=False),
                            len(cached.pending_outliers(_ds)))
        box = {"success": st.success, "info": st.info, "warning": st.warning}[look.level]
        box(f"**{look.title}**  \n{look.text}  \n**Next:** {look.action}")
        target = {"refit": "pages/kinematic.py", "diagnose": "pages/diagnose.py",
                  "uncertainty": "pages/uncertainty.py"}.get(look.step)
        if target is not None:
            st.page_link(target, label={"refit": "Kinematic model", "diagnose":
                                        "Compare and diagnose", "uncertainty":
                                        "Uncertainty"}[look.step], icon=":material/east:",
                         query_params=session.session_query())

# lazy tabs (issue 27): a tab's widgets (the simulator's form alone is some thirty, the
# upload tab's file fields each load their script and layout) are sent only while the tab
# is open, so the app's first screen does not draw them; the upload and project tabs stay
# drawn while their fields hold something the user put there (widgets.held)
DATA_TABS = ["Thesis sample", "Upload CSVs", "Other tools (MSL)", "Simulate a virtual CMM",
             "Project file"]
tab_thesis, tab_upload, tab_other, tab_sim, tab_proj = st.tabs(DATA_TABS, key="data_tab",
                                                               on_change="rerun",
                                                               bind="query-params")

with tab_thesis:
    st.write("The six ball-plate tables of thesis chapter 6 (tables 6.1-6.6) with the appendix 5 "
             "certificate, exactly as printed (including the values that look wrong).")
    loaded = st.session_state.get("ds_origin", {}).get("kind") == "thesis"
    # loaded already: the button starts them over, the settings back to their defaults
    if st.button("Reload the thesis tables (settings to defaults)" if loaded
                 else "Load thesis tables", key="load_thesis"):
        state.set_dataset(A.thesis_sources(), A.THESIS_ORIGIN)
        state.loaded("Loaded the thesis tables.")

with tab_upload:
    if tab_upload.open or upload.held():
        upload.upload_section()

with tab_other:
    if tab_other.open:
        msl_section()

with tab_sim:
    if tab_sim.open:
        simulate.simulate_section()

with tab_proj:
    if tab_proj.open or widgets.held("up_project"):
        project.project_section()

instruments.instruments_section()

# ---------------------------------------------------------------------------------------
# The current dataset: validation report
# ---------------------------------------------------------------------------------------
ds = cached.require_dataset()
s = st.session_state
st.header(f"Current dataset: {ds.name}")
m = ds.meas
c1, c2, c3, c4 = st.columns(4)
c1.metric("Probed ball centres", len(m))
c2.metric("Positions", len(ds.positions))
c3.metric("Probes", len(ds.probes))
c4.metric("Certificate", "yes" if ds.certificate is not None else "no")

st.subheader("Validation report")
counts = (m.groupby(["position", "probe"], sort=False).agg(
    balls=("ball", "nunique"), points=("ball", "size"), source=("source", "first"))
    .reset_index())
span = m.groupby("position", sort=False)[["mx_mm", "my_mm", "mz_mm"]].agg(
    lambda v: v.max() - v.min())
counts = counts.merge(span.rename(columns=lambda c: f"span_{c[1]}_mm").reset_index(),
                      on="position")
# a static table: the data grid's scripts would load with the app's first screen (issue 27)
widgets.static_table(counts, key="validation_counts")
problems = []
for pos, probe, miss in cio.missing_balls(m, ds.certificate):
    problems.append(f"{pos}/{probe}: missing ball(s) {', '.join(map(str, miss))}")
big = span.max(axis=1)
for pos, v in big.items():
    if v < 50:
        problems.append(f"{pos}: the balls span only {v:.1f} mm; check the units (mm).")
if problems:
    for p in problems:
        st.warning(p)
else:
    st.success("Units look like mm; every position has every ball of the certificate; no "
               "duplicates.")

st.subheader("Outliers (robust median/MAD across positions)")
rep = calls.safe(cached.cached_outliers, s["ds_key"], ds, what="Outlier detection")
if rep is not None:
    st.caption(f"Reference: {rep.reference}. Robust σ per axis: "
               + ", ".join(f"{a} {v:.2f} µm" for a, v in rep.scale_um.items())
               + "; threshold: " + ", ".join(f"{a} {v:.1f} µm"
                                             for a, v in rep.threshold_um.items()) + ".")
    if not rep.outliers:
        st.success("No coordinate is flagged.")
    else:
        # plain text: the summary at the top is the page's one warning of them
        st.write(f"{len(rep.outliers)} coordinate(s) flagged. They stay in the fit until you "
                 "tick them; nothing is dropped silently.")
        current = {tuple(e) for e in s["exclusions"]}
        flagged = rep.exclusions
        bcols = st.columns([1, 1, 4])
        bcols[0].button("Exclude all flagged", key="exclude_all", on_click=state.set_exclusions,
                        args=(flagged, True))
        bcols[1].button("Include all", key="include_all", on_click=state.set_exclusions,
                        args=(flagged, False))
        by_obs = {}
        for o in rep.outliers:
            by_obs.setdefault((o["position"], o["probe"], o["ball"]), []).append(o)
        for trip, os_ in by_obs.items():
            wk = f"w_ex_{trip[0]}_{trip[1]}_{trip[2]}"
            if wk not in s:
                s[wk] = trip in current
            # "robust score", not "z": next to an axis letter, z reads as the z axis.
            detail = "; ".join(f"{o['axis']} {o['deviation_um']:+.1f} µm (robust score "
                               f"{o['robust_z']:+.1f})" for o in os_)
            src = os_[0]
            label = (f"Exclude {trip[0]} probe {trip[1]} ball {trip[2]}: {detail} "
                     f"[{src['source']}, row {src['row']}]")
            st.checkbox(label, key=wk, on_change=state.toggle_exclusion, args=(trip, wk))
    # exclusions a project restored that the detector does not flag: shown, never hidden
    others = sorted({tuple(e) for e in s["exclusions"]} - {tuple(t) for t in rep.exclusions})
    if others:
        o1, o2 = st.columns([4, 1])
        o1.info("Also excluded (restored, not flagged by the detector): "
                + "; ".join(f"{p} probe {q} ball {b}" for p, q, b in others) + ".")
        o2.button("Include them again", key="include_unflagged", on_click=state.set_exclusions,
                  args=(others, False))

st.subheader("Placements in the machine volume")
with calls.guarded("Placement views"):
    # three flat views as plain SVG by default: the app's first screen then needs none of
    # Plotly's 4.7 MB of script (issue 27); the WebGL scene on request
    if st.toggle("3-D view", key="w_place_3d",
                 help="Rotate the placements in 3-D (slower to draw than the three views)."):
        st.plotly_chart(cached.figure("placements", (s["ds_key"],), A.fig_placements, ds),
                        key="fig_placements")
    else:
        widgets.svg_figure(cached.figure("placement_views", (s["ds_key"],),
                                       A.placement_views_svg, ds), "placement_views")
        st.caption("Probed ball centres (tip centres, machine frame, mm); the dashed box is "
                   "the working volume. Hover a marker for its placement, stylus and "
                   "ball.")

# lazy expanders: their tables are built and drawn only while open (issue 27)
with st.expander("Measurements (as read, mm)", key="w_meas_open", on_change="rerun") as box:
    if box.open:
        widgets.dataframe(m, hide_index=True, key="meas_table")
with st.expander("Setup (JSON)", key="w_setup_open", on_change="rerun") as box:
    # a JSON tree rather than highlighted code: the highlighter's 1.6 MB of script would
    # load with the app's first screen (issue 27)
    if box.open:
        st.json(ds.setup.raw, expanded=2)
