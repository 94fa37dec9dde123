"""Compensate and export: correct points; download results, report and project file."""

import io
import json

import pandas as pd
import streamlit as st

from cmm_core import analysis as A
from cmm_core import export as ex
from cmm_core import io as cio
from cmm_core.model import correction_columns
from pages.ui import cached, calls, session, widgets
from pages.ui.panels.task import task_section

st.title("Compensate and export")
ds, r = cached.require_fit()
s = st.session_state
args = cached.fit_key()
# every file below names this software, the data's files by their SHA-256 and the machine
prov = s["sources"].provenance()
obs = r.problem.obs


def fname(name: str) -> str:
    """A download's file name, prefixed with the dataset's: two datasets' downloads never
    overwrite each other in one folder."""
    return ex.download_name(ds.name, name)


MODEL_FILE = fname("cmm_model.json")  # the fitted model's download name, the results' source

st.subheader("Correct measured points")
st.write("Upload reported tip centres `probe,x_mm,y_mm,z_mm` (machine axes, mm; extra columns "
         "are kept). Each gets the corrected point `xc_mm, yc_mm, zc_mm` (reported + error) "
         "and the standard uncertainty of the correction in µm.")
st.caption(f"Sign of every error here and in the report: {A.ERROR_CONVENTION}.")
st.caption("Which uncertainty to quote: `u_x/y/z_um` here is the standard uncertainty "
           "(k = 1) of each point's correction in machine coordinates. It includes a common "
           "translation and rotation of all corrected points, which a ball plate fixes only "
           "through the error functions' zero at the axis origins, so it grows away from "
           "them. For lengths, distances and form measured with the corrected machine that "
           "common part cancels: quote U2/U3 of the Uncertainty page, which remove it.")
if "backlash" in r.problem.layout.blocks:
    st.caption("This model has backlash: each point is also corrected for the direction its "
               "axes last moved in, taken from the file's row order (or `time_min`); before "
               "an axis first moves its direction is unknown and half the span is added to "
               "the uncertainty (columns `approach_x/y/z`: +1, −1, 0 unknown).")
# columns the model's own blocks read from the points besides the coordinates (each block
# says which: the scale temperatures of machine_thermal, the order of backlash)
extra_cols = correction_columns(r.problem.blocks)
if "machine_thermal" in r.problem.layout.blocks:
    st.caption("This model has the scales' thermal expansion (machine_thermal): each point "
               "needs the scale temperatures of the fitted axes in columns `temp_x_C`, "
               "`temp_y_C`, `temp_z_C` (°C) of the points file.")
up = st.file_uploader("Points to correct (CSV)", type=["csv", "txt"], key="up_points")
# an uploaded file always wins: correcting the example instead would let a user download
# corrections of points they did not ask for
use_example = up is None and st.checkbox(
    "Use example points (the measured ball centres of this dataset) until a file is "
    "uploaded", value=True, key="w_points_example")


@st.cache_data(show_spinner=False, max_entries=16)
def corrected(args, content_key, _points, _r):
    return ex.compensate_points(_r, _points)


points = None
if up is not None:
    points = calls.safe(ex.read_points, io.BytesIO(up.getvalue()), name=up.name, what="Points file")
    ckey = (up.name, len(up.getvalue()), hash(up.getvalue()))
    points_prov = prov.with_inputs([cio.input_file(up.name, up.getvalue())])
elif use_example:
    t = r.table
    points = pd.DataFrame({"probe": t["probe"].astype(str), "x_mm": t["mx_mm"],
                           "y_mm": t["my_mm"], "z_mm": t["mz_mm"],
                           "position": t["position"], "ball": t["ball"],
                           # what the model reads besides (a machine_thermal model
                           # refuses points without their scale temperatures)
                           **{c: t[c] for c in extra_cols if c in t}}).head(50)
    ckey = "example"
    points_prov = prov  # the measured centres of the data it names
corr = None
if points is not None:
    corr = calls.safe(corrected, args, ckey, points, r, what="Compensation")
if corr is not None:
    widgets.misfit_banner(r)  # the corrections' uncertainties never hide a failed χ² test
    view = corr.copy()
    for a in "xyz":
        view[f"e{a}_um"] = A.measured_error_um(view[f"{a}_mm"], view[f"{a}c_mm"])
    widgets.dataframe(view, hide_index=True, key="corrected_table",
                 column_config={c: st.column_config.NumberColumn(format="%.5f")
                                for c in view.columns if c.endswith("_mm")}
                 | {c: st.column_config.NumberColumn(format="%.3f")
                    for c in view.columns if c.endswith("_um")})
    n_ext = int((corr["extrapolated"] != "").sum())
    if n_ext:
        st.warning(f"{n_ext} of {len(corr)} point(s) lie outside the region the fit measured "
                   "(see the 'extrapolated' column): their corrections extrapolate the "
                   "polynomials and their uncertainties do not show it.")
    if r.unidentifiable:
        st.warning("The model has parameters the data do not determine: the corrections "
                   "use an arbitrary (minimum-norm) choice for them and carry no "
                   "uncertainty. Add placements on the Kinematic model page first.")
    st.download_button("Download corrected points (CSV)",
                       ex.corrected_csv(corr, points_prov), fname("corrected_points.csv"),
                       "text/csv", key="dl_corrected", on_click="ignore")

task_section()

st.subheader("Downloads")
c1, c2, c3 = st.columns(3)
c1.download_button("Fitted parameters with uncertainties (CSV)", ex.parameters_csv(r, prov),
                   fname("parameters.csv"), "text/csv", key="dl_parameters", on_click="ignore")
c2.download_button("Residuals (CSV)", ex.residuals_csv(r, prov), fname("residuals.csv"), "text/csv",
                   key="dl_residuals", on_click="ignore")

with st.container(border=True):
    st.markdown("**Error-map grid** (for checking and plotting: the error e = true − "
                "reported at each node for one of the fitted styli, µm, with standard "
                "uncertainties, k = 1). For a controller use the *compensation table* below: "
                "the same corrections, its probe and coverage factor chosen there, and a "
                "header a controller's import can check.")
    g1, g2 = st.columns(2)
    step = g1.number_input("Grid step (mm)", 10.0, 500.0, 100.0, step=10.0, key="w_grid_step")
    gprobe = g2.selectbox("Probe", obs.probes, key="w_grid_probe")

    @st.cache_data(show_spinner="Computing the grid…", max_entries=16)
    def grid_csv(args, step, probe, _r, _prov):
        g = ex.error_map_grid(_r, step_mm=step, probe=probe)
        return ex.error_map_csv(_r, g, probe, _prov), len(g)

    out = calls.safe(grid_csv, args, float(step), gprobe, r, prov, what="Error map")
    if out is not None:
        text, n_nodes = out
        st.caption(f"{n_nodes} grid nodes over the working volume "
                   f"{' × '.join(f'{v:g}' for v in obs.range_mm)} mm.")
        st.download_button("Download error-map grid (CSV)", text, fname("error_map.csv"), "text/csv",
                           key="dl_grid", on_click="ignore")

with st.container(border=True):
    st.markdown("**Compensation tables and results for a quality system** "
                "(formats in `docs/compensation.md`): a 3-D grid of corrections "
                "(true − indicated, added to the reading, µm) with uncertainties; the "
                "per-axis error functions and squareness a controller needs (µm, µrad); the "
                "fitted model's parameters with uncertainties and its χ² test as JSON and "
                "QIF-like XML; and the calibration as a QIF 3.0 document (schema-valid: "
                "the CMM, the measured ball centres, the parameters in its extension; "
                "`docs/formats.md`, \"QIF 3.0\"). The same files as `cmm-error-lab export "
                "cmm_model.json` gives from the *Fitted model* download above (only the "
                "creation time differs; `--qif` reads the data files too); every fitted "
                "parameter, plate and placements included, is in the parameters CSV.")
    k1, k2, k3 = st.columns(3)
    cstep = k1.number_input("Table step (mm)", 25.0, 500.0, 100.0, step=25.0,
                            key="w_comp_step")
    origin = "none (ram reference point)"
    cprobe = k2.selectbox("Grid probe", [origin, *obs.probes], key="w_comp_probe",
                          help="The per-axis tables do not depend on the probe.")
    kfac = k3.number_input("Coverage factor k", 1.0, 10.0, 2.0, step=0.5, key="w_comp_k")

    @st.cache_data(show_spinner="Computing the compensation tables…", max_entries=16)
    def comp_tables(args, step, probe, _r, _prov):
        if ex.as_model(_r).undetermined:
            return None
        g = ex.compensation_grid(_r, step, probe=probe)
        src = MODEL_FILE
        return (ex.grid_csv(_r, g, probe, src, _prov),
                ex.axis_tables_zip(_r, step, src, provenance=_prov), len(g))

    @st.cache_data(show_spinner=False, max_entries=16)
    def results_files(args, k, _r, _prov):
        # of the model, named as its download: what the command line writes from that file
        m = ex.as_model(_r)
        return (ex.results_json(m, coverage_factor=k, source=MODEL_FILE, provenance=_prov),
                ex.results_xml(m, coverage_factor=k, source=MODEL_FILE, provenance=_prov))

    @st.cache_data(show_spinner="Writing the QIF document…", max_entries=16)
    def qif_file(args, k, _r, _ds, _prov):
        # of the model, as the results files: the parameters `export --qif` writes from
        # the model file and these data
        return ex.qif_document(ex.as_model(_r), _ds, provenance=_prov, coverage_factor=k)

    tables = calls.safe(comp_tables, args, float(cstep), None if cprobe == origin else cprobe,
                    r, prov, what="Compensation tables")
    files = calls.safe(results_files, args, float(kfac), r, prov, what="Results files")
    # QIF states the nominal centres: a self-calibrated plate has none to state
    qif = None if ds.certificate is None else calls.safe(
        qif_file, args, float(kfac), r, ds, prov, what="QIF document")
    t1, t2, t3, t4, t5 = st.columns(5)
    if tables is not None:
        t1.download_button("Grid compensation table (CSV)", tables[0], fname("compensation_grid.csv"),
                           "text/csv", key="dl_comp_grid", on_click="ignore",
                           help=f"{tables[2]} nodes; header: units, sign, layout, probe, "
                                "grid, model and its χ² test.")
        t2.download_button("Per-axis tables (zip of CSV)", tables[1], fname("axis_tables.zip"),
                           "application/zip", key="dl_axis_tables", on_click="ignore",
                           help="axis_x/y/z.csv: the six error functions of each axis; "
                                "squareness.csv.")
    elif ex.as_model(r).undetermined:
        t1.info("No compensation tables: the data do not determine every kinematic "
                "combination, so the corrections would be an arbitrary choice.")
    if files is not None:
        t3.download_button("Results (JSON)", files[0], fname("cmm_results.json"), "application/json",
                           key="dl_results_json", on_click="ignore")
        t4.download_button("Results (QIF-like XML)", files[1], fname("cmm_results.xml"),
                           "application/xml", key="dl_results_xml", on_click="ignore")
    if qif is not None:
        t5.download_button("QIF 3.0 (.qif)", qif, fname("cmm_calibration.qif"),
                           "application/xml", key="dl_qif", on_click="ignore",
                           help="ANSI/DMSC QIF 3.0 document: the CMM, each placement's "
                                "measured ball centres (labelled position/probe/ball, "
                                "σ as their uncertainty), the fitted parameters with "
                                "U = k·u and the χ² test in its extension, provenance in "
                                "its header. The Data page (and `cmm-error-lab fit`) "
                                "reads it back.")
    elif ds.certificate is None:
        t5.info("No QIF document: it states the plate's nominal ball centres, and this "
                "dataset has no certificate (self-calibrated plate).")


# One analysis record from the session: the report, the record file and the project file
# all come from it, and `cmm-error-lab report` gives the same report from the record.
st.checkbox("Include a GP summary of the measured errors in the report (mean and "
                        "kernel as chosen on the Gaussian process page; adds a few seconds)",
                        key="w_report_gp")
record = calls.safe(session.session_record, s, what="Analysis record")


@st.cache_data(show_spinner=False, max_entries=4)
def report_html(record_json, _record):
    return A.analysis_report(_record)


def _report_bytes():
    # runs on a separate thread when clicked: only local values, no session state
    return report_html(A.record_to_json(record), record).encode("utf-8")


def _project_text():
    # runs on a separate thread when clicked: only local values, no session state
    return A.record_to_project_json(record)


if record is not None:
    c3.download_button("HTML report (self-contained)", _report_bytes, fname("cmm_report.html"),
                       "text/html", key="dl_report", on_click="ignore",
                       help="Summary with the fit's χ² test, figures (plotly embedded once, "
                            "no network needed), uncertainty, parameter and residual tables. "
                            "The same as `cmm-error-lab report ANALYSIS.json`.")
    c2.download_button("Analysis record (ANALYSIS.json)", A.record_to_json(record),
                       fname("ANALYSIS.json"), "application/json", key="dl_analysis",
                       on_click="ignore",
                       help="Data, selection, exclusions, model, σ and report choices: "
                            "`cmm-error-lab report ANALYSIS.json --out REPORT.html` "
                            "reproduces this report.")
    c1.download_button("Project file (JSON)", _project_text, fname("cmm_project.json"),
                       "application/json", key="dl_project", on_click="ignore",
                       help="Restores the dataset, model, exclusions and history on the "
                            "Data page.")
c3.download_button("Fitted model (JSON, for `cmm_core compensate`)",
                   lambda: json.dumps(ex.model_to_dict(r, prov), indent=1), MODEL_FILE,
                   "application/json", key="dl_model", on_click="ignore")
c2.caption(f"Model `{r.spec}`, RMS {r.rms_um:.3f} µm, {r.n_obs} observations, "
           f"{len(s['exclusions'])} excluded. CSV files are safe to open in a spreadsheet "
           "(text cells that could be formulas are prefixed with an apostrophe).")
if r.unidentifiable:
    st.warning("Some parameters are not determined by the data: their uncertainties are "
               "empty in the exports.")
