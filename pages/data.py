"""Data page: load the thesis tables, upload CSVs, simulate, restore a project, add
instrument files (laser runs, step gauges); validate."""

import io
import json
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import streamlit as st

from cmm_core import analysis as A
from cmm_core import io as cio
from cmm_core import model as M
from cmm_core.io import THESIS_POSITIONS
from cmm_core.machine import DEFAULT_LAYOUT, LAYOUTS
from cmm_core.model import (
    simulate,
    simulate_laser,
    simulate_step_gauge,
    simulator_effects,
    thesis_machine_setup,
    write_laser,
    write_step_gauge,
)
from pages.ui import cached, calls, session, state, widgets
from pages.ui.panels.mapping import mapping_panel
from pages.ui.panels.msl import msl_section

st.title("Data")
st.caption("Ball-plate measurements, setup and certificate. Files are in mm; the screen "
           "shows µm.")
widgets.flash()


MAX_SHOWN = cio.MAX_PROBLEMS  # rows of the upload problem table
LAYOUT_NAMES = {  # docs/layouts.md, in words
    "moving_bridge_fxyz": "Moving bridge, bridge along x (thesis machine)",
    "moving_bridge_fyxz": "Moving bridge, bridge along y",
    "fixed_bridge_xfyz": "Fixed bridge, table moving in x",
    "fixed_bridge_yfxz": "Fixed bridge, table moving in y",
    "gantry_fxyz": "Gantry, beam along x",
    "gantry_fyxz": "Gantry, beam along y",
    "horizontal_arm_fxzy": "Horizontal arm, column along x, arm in y",
    "horizontal_arm_fyzx": "Horizontal arm, column along y, arm in x",
}


def _instrument_columns(kind: str) -> str | None:
    """The columns of an instrument file of ``kind`` (``io_instruments``), for the help."""

    need = getattr(M, f"{kind.upper()}_COLUMNS", None)
    opt = getattr(M, f"{kind.upper()}_OPTIONAL", ())
    if not need:
        return None
    return (f"Columns {', '.join(need)}" + (f"; optional {', '.join(opt)}" if opt else "")
            + ". Machine axes, mm; errors and u in µm (docs/instruments.md).")


def _problem(file, problem, hint="", row=None, column="", more=0):
    """One row of the upload problem table; ``more`` counts problems a note row stands for."""
    return {"file": file or "", "row": row, "column": column or "", "problem": problem,
            "hint": hint or "", "_more": more}


def _count(problems):
    """Problems in a report: listed rows plus those the note rows say are not listed."""
    return sum(p["_more"] or 1 for p in problems)


def _problem_rows(exc, file=""):
    """Every problem an exception carries, as rows of the upload problem table.

    A :class:`cio.DataError` lists all problems of its file (capped by the core); when it
    found more than it lists, a last row says how many are not shown.
    """
    if not isinstance(exc, cio.DataError):
        return [_problem(file, calls.describe_error(exc))]
    rows = [_problem(p.file, p.detail, p.hint, p.row, p.column) for p in exc.problems]
    hidden = exc.n_problems - len(exc.problems)
    if hidden > 0:
        rows.append(_problem(exc.file, f"... and {hidden} more problem(s) not listed.",
                             "fix these and load again to see the rest.", more=hidden))
    return rows


def _capped(problems):
    """At most MAX_SHOWN rows (several bad files could list 50 each), plus a note."""
    if len(problems) <= MAX_SHOWN:
        return problems
    rest = problems[MAX_SHOWN:]
    note = _problem("", f"... and {_count(rest)} more problem(s) not listed.",
                    "fix the problems listed and load again.", more=_count(rest))
    return problems[:MAX_SHOWN] + [note]


def _read_note(name, attrs):
    """Say how a file not separated by commas was read, so nothing happens unseen."""
    delim = attrs.get("delimiter", ",")
    if delim == ",":
        return None
    kind = {";": "semicolon", "\t": "tab"}.get(delim, repr(delim))
    comma = " with decimal commas" if attrs.get("decimal_comma") else ""
    return f"{name} was read as {kind}-separated{comma}."


def _checked_text(upload, reader, problems):
    """The uploaded file's text if ``reader`` accepts it, else None with the problems noted."""
    try:
        text = upload.getvalue().decode("utf-8-sig")
        reader(io.StringIO(text), name=upload.name)
        return text
    except UnicodeDecodeError:
        problems.append(_problem(upload.name, "is not UTF-8 text.",
                                 "save it as UTF-8 CSV/JSON."))
    except Exception as exc:  # noqa: BLE001 - a message, never a traceback
        problems.extend(_problem_rows(exc, upload.name))
    return None


def _checked_measurements(meas_files, problems, notes):
    """(name, text) of every measurement file that reads; problems of the others noted."""
    meas, seen = [], {}
    for f in meas_files:
        data = f.getvalue()
        if data in seen:
            # one line, not one "appears twice" per ball of the combined table
            problems.append(_problem(f.name, f"has the same content as {seen[data]}: the "
                                     "file was uploaded twice.", "remove one of them."))
            continue
        seen[data] = f.name
        try:
            df = cio.read_measurements(io.BytesIO(data), name=f.name)
            meas.append((f.name, data.decode("utf-8-sig")))
        except Exception as exc:  # noqa: BLE001 - a message, never a traceback
            foreign = cio.sniff(data)  # another tool's file: say which reader takes it
            problems.extend([_problem(f.name, foreign, "use the 'Other tools' tab or the "
                                      "mapped import below.")] if foreign
                            else _problem_rows(exc, f.name))
        else:
            notes.append(_read_note(f.name, df.attrs))
    return meas


def _positions_of(meas):
    """Position names in the measurement files that read (long form: the column; thesis
    form: the file name)."""
    out = set()
    for name, text in meas:
        try:
            df = cio.read_measurements(io.StringIO(text), name=name)
        except Exception:  # noqa: BLE001 - already reported
            continue
        out |= set(df["position"].astype(str))
    return out


def _dataset_name(label, meas):
    """The user's label, else the file names with the upload's number, so that two
    uploads of files with the same names (measurements.csv) are told apart."""
    if label and label.strip():
        return label.strip()[:80]
    n = st.session_state.get("upload_count", 0) + 1
    return f"{', '.join(name for name, _ in meas)[:60]} (upload {n})"


# how the upload states the certificate's uncertainty (issue 24: never assumed); comments,
# not strings under the names: Streamlit's "magic" writes a page script's bare strings
CERT_U_CHOICES = ("As the certificate's u columns or the setup state it",
                  "U(k) = a ⊕ b·L, entered here", "Exact (a noise-free simulation)")
CERT_U_SOURCE = "entered on the Data page"


def _certificate_statement_inputs(sfx):
    """The certificate statement of the setup's ``certificate`` section, as entered (None:
    the file's u columns or the setup's own statement)."""
    choice = st.radio("Certificate uncertainty (for a certificate without u_x_um, u_y_um, "
                      "u_z_um columns)", CERT_U_CHOICES, key=f"up_cert_u{sfx}",
                      help="No fit assumes a certificate uncertainty: it comes from the "
                           "file's u columns, the setup's certificate statement, or what "
                           "you enter here (it replaces the setup's statement).")
    if choice == CERT_U_CHOICES[2]:
        return {"exact": True, "source": CERT_U_SOURCE}
    if choice != CERT_U_CHOICES[1]:
        return None
    c1, c2, c3, c4 = st.columns(4)
    a = c1.number_input("a (µm)", min_value=0.0, max_value=100.0, value=0.0, step=0.01,
                        format="%.3f", key=f"up_cert_a{sfx}",
                        help="constant part of the expanded uncertainty U, µm")
    b = c2.number_input("b (µm per mm)", min_value=0.0, max_value=1.0, value=0.0,
                        step=1e-4, format="%.5f", key=f"up_cert_b{sfx}",
                        help="length part of U, µm per mm of the distance L from ball 1")
    k = c3.number_input("k", min_value=1.0, max_value=3.0, value=2.0, step=0.5,
                        key=f"up_cert_k{sfx}", help="coverage factor of U")
    combine = c4.selectbox("⊕", ("quadrature", "linear"), key=f"up_cert_combine{sfx}",
                           help="quadrature: U = sqrt(a² + (b·L)²); linear: U = a + b·L")
    return {"U_um": [float(a), float(b)], "k": float(k), "combine": combine,
            "source": CERT_U_SOURCE}


def _with_statement(setup_text, statement, problems):
    """The setup text with the entered certificate statement as its ``certificate``
    section, checked by the setup reader (None with the problem noted when refused)."""
    raw = json.loads(setup_text)
    raw["certificate"] = statement
    text = json.dumps(raw, indent=1)
    try:
        cio.read_setup(io.StringIO(text), name="setup.json")
    except Exception as exc:  # noqa: BLE001 - a message, never a traceback
        problems.extend(_problem_rows(exc, "certificate uncertainty (entered)"))
        return None
    return text


def _validate_upload(meas_files, setup_file, cert_file, use_thesis, label="", mapped=None,
                     cert_statement=None):
    """Check every file on its own, then together.

    Returns
    -------
    files : dict or None
        The dataset files when everything loads.
    problems : list of dict
        Rows of the problem table (every problem of every file, capped).
    notes : list of str
        How files not separated by commas were read.
    """
    problems, notes = [], []
    meas = _checked_measurements(meas_files, problems, notes)
    if mapped is not None:  # a table from other software, already mapped to the long form
        meas.append(tuple(mapped[:2]))
        notes.append(f"{mapped[0]}: read through the column mapping.")
    thesis = state.thesis_files()
    setup_text, cert = None, None
    setup_source = cert_source = None
    if setup_file is not None:
        setup_text = _checked_text(setup_file, cio.read_setup, problems)
        setup_source = f"{setup_file.name} (uploaded)"
    elif use_thesis:
        missing = sorted(_positions_of(meas) - set(THESIS_POSITIONS))
        if missing:
            # the thesis placements cannot place these positions: ask for their setup
            problems.append(_problem(
                "setup.json", f"no setup uploaded, and the thesis setup that would stand in "
                f"does not know position(s) {', '.join(missing[:8])}"
                + (" ..." if len(missing) > 8 else "") + ", so their placement in the "
                "machine is unknown.", "upload the setup JSON of these measurements "
                "(positions, placements and probe offsets: docs/formats.md#setup)."))
        setup_text = thesis["setup"]
        setup_source = "thesis setup (stand-in: no setup uploaded)"
        notes.append("The thesis setup (the placements of chapter 6) stands in for the "
                     "setup not uploaded.")
    else:
        problems.append(_problem("setup.json", "no setup given.",
                                 "upload a setup JSON (docs/formats.md#setup) or tick 'use "
                                 "the thesis setup'."))
    if cert_statement is not None and setup_text is not None:
        setup_text = _with_statement(setup_text, cert_statement, problems)
        notes.append("Certificate uncertainty: " + (
            "exact" if cert_statement.get("exact") else
            "U(k={k:g}) = {a:g} ⊕ {b:g}·L µm ({c})".format(
                k=cert_statement["k"], a=cert_statement["U_um"][0],
                b=cert_statement["U_um"][1], c=cert_statement["combine"]))
            + f", {CERT_U_SOURCE}; a certificate's own u columns take precedence.")
    if cert_file is not None:
        text = _checked_text(cert_file, cio.read_certificate, problems)
        cert = None if text is None else (cert_file.name, text)
        cert_source = f"{cert_file.name} (uploaded)"
    elif use_thesis and setup_file is None:
        # the thesis certificate only belongs with the thesis plate and placements: with a
        # setup of their own the user measured another plate
        cert = thesis["certificate"]
        cert_source = "thesis certificate (stand-in: none uploaded)"
        notes.append("The thesis certificate (appendix 5) stands in for the certificate "
                     "not uploaded.")
    else:
        cert_source = "none (plate geometry self-calibrated)"
        notes.append("No certificate: the plate geometry is fitted from the positions "
                     "(self-calibration, plate free).")
    if not meas_files and mapped is None:
        problems.append(_problem("", "no measurement file given.", "upload one long-form "
                                 "CSV or one thesis-form CSV per position."))
    if problems:
        return None, _capped(problems), notes
    files = {"name": _dataset_name(label, meas), "kind": "upload",
             "measurements": meas, "setup": setup_text, "certificate": cert,
             "setup_source": setup_source, "certificate_source": cert_source}
    if mapped is not None and len(mapped) == 5 and None not in (mapped[3], mapped[4]):
        # the source table and its mapping travel into the analysis record and project
        files["mapped"] = {mapped[0]: tuple(mapped[2:])}
    try:
        state.load_files(state.files_key(files), files)
    except Exception as exc:  # noqa: BLE001 - a message, never a traceback
        return None, _capped(_problem_rows(exc)), notes
    return files, [], [n for n in notes if n]


def _simulated_instruments(sim, seed: int) -> list:
    """A laser positioning run along x and a step gauge along a diagonal of the volume,
    measured on the simulation's true machine, as (kind, file name, text) triples."""

    rng = np.asarray(sim.dataset.setup.range_mm, float)
    laser = simulate_laser(sim, "x", [0.0, 0.1 * rng[1], 0.1 * rng[2]],
                               np.linspace(0.0, rng[0], 25), u_um=0.2, seed=seed + 1,
                               run="x_positioning", source="simulated_laser_x.csv")
    start, end = 0.1 * rng, np.array([0.9, 0.85, 0.6]) * rng
    n = int(np.linalg.norm(end - start) // 100)
    sg = simulate_step_gauge(sim, start, end, np.arange(1, n + 1) * 100.0, u_um=0.3,
                                 seed=seed + 2, source="simulated_step_gauge.csv")
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for kind, item, write in (("laser", laser, write_laser),
                                  ("step_gauge", sg, write_step_gauge)):
            path = Path(tmp) / item.source
            write(item, path)
            out.append((kind, item.source, path.read_text()))
    return out


def _loaded(message):
    """After any successful load: the old upload report no longer applies."""
    st.session_state.pop("upload_report", None)
    st.session_state.pop("instrument_errors", None)
    st.session_state["flash"] = ("success", message)
    st.rerun()


def _show_upload_report():
    """The last failed upload's problems, kept until the next load attempt or success
    (a table drawn only in the run of the button click vanished at the next interaction)."""
    report = st.session_state.get("upload_report")
    if not report:
        return
    st.error(f"Validation found {report['count']} problem(s); the current dataset is "
             "unchanged."
             + (" The upload fields are cleared: upload the corrected files (all of "
                "them)." if report.get("cleared") else ""))
    table = pd.DataFrame(report["problems"]).drop(columns="_more")
    table["row"] = table["row"].astype("Int64")  # whole row numbers, blank when none
    widgets.dataframe(table, hide_index=True, key="upload_problems")
    # a table cell cuts long text ("did you mea…"): every problem and hint in full below
    with st.expander("Each problem in full"):
        st.markdown("\n".join(
            "- " + ", ".join(x for x in (f"**{p['file']}**" if p["file"] else "",
                                         f"row {p['row']}" if p["row"] is not None else "",
                                         f"column {p['column']}" if p["column"] else "")
                             if x)
            + f": {p['problem']}" + (f" *{p['hint']}*" if p["hint"] else "")
            for p in report["problems"]))


def upload_section():
    """The upload tab: measurement, setup and certificate files, checked and loaded."""
    st.write("Long form: `position,probe,ball,x_mm,y_mm,z_mm[,time_min,temp_C,repeat]` in one "
             "file, or thesis form `ball,x_mm,y_mm,z_mm`, one file per position (named by the "
             "position). Plus the setup JSON and, optionally, the certificate.")
    # after each successful load the uploaders start empty (new keys): the next upload
    # replaces the files instead of adding to them
    gen = st.session_state.get("upload_gen", 0)
    sfx = "" if gen == 0 else f"_{gen}"
    up_meas = st.file_uploader("Measurement CSV file(s)", type=["csv", "txt"],
                               accept_multiple_files=True, key=f"up_meas{sfx}")
    with st.expander("A table from other software or a DMIS output file (.dmo), mapped"):
        mapped_now = mapping_panel(f"map{sfx}")
    if mapped_now is not None:
        st.session_state["mapped_meas"] = (mapped_now.csv_name, mapped_now.csv_text,
                                           mapped_now.name, mapped_now.source_text,
                                           mapped_now.mapping)
    if st.session_state.get("mapped_meas"):
        st.caption(f"Mapped table ready: {st.session_state['mapped_meas'][0]} (loaded with "
                   "the setup below by 'Load uploaded files').")
    c1, c2 = st.columns(2)
    up_setup = c1.file_uploader("Setup (JSON)", type=["json"], key=f"up_setup{sfx}")
    up_cert = c2.file_uploader("Certificate (CSV, optional)", type=["csv", "txt"],
                               key=f"up_cert{sfx}")
    cert_statement = _certificate_statement_inputs(sfx)
    up_label = st.text_input("Dataset name (optional)", key=f"up_label{sfx}",
                             placeholder="e.g. the folder or job name",
                             help="Shown in the sidebar, the report and the project file. "
                                  "Empty: the file names and the upload's number.")
    use_thesis = st.checkbox("Use the thesis setup for a setup not uploaded (and the thesis "
                             "certificate with it)", value=True, key="use_thesis_setup",
                             help="With a setup of your own, the thesis certificate is never "
                                  "used: your plate is another plate. Without a certificate "
                                  "the plate is self-calibrated.")
    if st.button("Load uploaded files", key="load_upload", type="primary"):
        st.session_state.pop("upload_report", None)
        files, problems, notes = _validate_upload(up_meas or [], up_setup, up_cert,
                                                  use_thesis, up_label,
                                                  st.session_state.get("mapped_meas"),
                                                  cert_statement)
        if problems:
            # the fields are cleared after a refusal too: a corrected file must not be
            # judged together with the refused one it replaces (issue 27)
            st.session_state["upload_report"] = {"problems": problems,
                                                 "count": _count(problems),
                                                 "cleared": True}
            st.session_state["upload_gen"] = gen + 1
            st.rerun()  # draw the emptied fields now; the report is kept in the state
        else:
            state.set_dataset(files)
            st.session_state["upload_count"] = st.session_state.get("upload_count", 0) + 1
            st.session_state["upload_gen"] = gen + 1
            st.session_state.pop("mapped_meas", None)
            _loaded(" ".join([f"Loaded {len(files['measurements'])} uploaded file(s) as "
                              f"'{files['name']}'."] + notes
                             + ["The upload fields are cleared: the next upload replaces "
                                "these files."]))
    _show_upload_report()


def project_section():
    """The project tab: a project file restores a whole analysis."""
    st.write("A project file (JSON, from *Compensate and export*) restores the dataset, model, "
             "exclusions and diagnosis history.")
    up_proj = st.file_uploader("Project file (JSON)", type=["json"], key="up_project")
    if st.button("Restore project", key="restore_project", disabled=up_proj is None):
        # the core reads the whole file (analysis.record_from_project: every part's shape
        # and value, one line naming the key) before anything of the session changes
        try:
            note = session.restore_project(up_proj.getvalue(), up_proj.name)
        except Exception as exc:  # noqa: BLE001 - a message, never a traceback
            st.error(f"The project does not restore: {calls.describe_error(exc)}")
        else:
            _loaded(f"Restored project '{st.session_state['ds_files']['name']}'.{note}")


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
    if st.button("Load thesis tables", key="load_thesis"):
        state.set_dataset(state.thesis_files())
        _loaded("Loaded the thesis tables.")

with tab_upload:
    if tab_upload.open or widgets.held("up_meas", "up_setup", "up_cert", "map",
                                     "upload_report", text=("up_label",),
                                     changed={"up_cert_u": CERT_U_CHOICES[0],
                                              "use_thesis_setup": True}):
        upload_section()

with tab_other:
    if tab_other.open:
        msl_section()

with tab_sim:
    if tab_sim.open:
        st.write("A virtual CMM with known errors measuring the thesis placements: choose the "
                 "noise, the plate form, hidden effects and the measurement order; the truth is "
                 "kept for comparison.")
        c1, c2, c3, c4 = st.columns(4)
        seed = c1.number_input("Seed", 0, 10_000, 0, key="sim_seed")
        noise = c2.number_input("Noise σ (µm)", 0.0, 10.0, 0.5, 0.1, key="sim_noise")
        rnd_um = c3.number_input("Translational errors (µm, 1σ)", 0.0, 50.0, 1.0, key="sim_rum")
        rnd_urad = c4.number_input("Rotational errors (µrad, 1σ)", 0.0, 50.0, 1.0, key="sim_rurad")
        c1, c2, c3, c4 = st.columns(4)
        form = c1.number_input("Plate form (µm, 1σ)", 0.0, 20.0, 2.0, key="sim_form")
        order = c2.selectbox("Measurement order", ["row", "serpentine", "random"], key="sim_order")
        korder = c3.selectbox("Polynomial order of the true errors", [1, 2, 3, 4, 5], index=1,
                              key="sim_korder")
        interleave = c4.checkbox("Probes interleaved", key="sim_interleave")
        c1, c2 = st.columns([2, 2])
        layout = c1.selectbox("Machine layout", list(LAYOUTS), key="sim_layout",
                              format_func=lambda k: f"{LAYOUT_NAMES.get(k, k)} ({k})",
                              help="How the carriages are stacked and which one moves the table "
                                   "(docs/layouts.md). The thesis placements are measured on it.")
        sim_inst = c2.checkbox("Also simulate a laser run along x and a step gauge",
                               key="sim_instruments",
                               help="Measured on the same true machine (laser u 0.2 µm, step "
                                    "gauge u 0.3 µm) and fitted jointly with the plate: the "
                                    "Kinematic model page then shows how much they lower each "
                                    "coefficient's uncertainty.")
        st.markdown("**Hidden effects**")
        # one checkbox per effect block of the registry (cmm_core.model.simulator_effects):
        # a new effect appears here with its block, nothing to add to the page
        eff = {}
        cols = st.columns(4)
        for k, e in enumerate(simulator_effects()):
            col = cols[k % 4]
            if col.checkbox(e.label, key=f"sim_{e.token}", help=e.help or None):
                eff[e.token] = e.config({p.key: col.number_input(
                    p.label, p.low, p.high, p.default, p.step, key=f"sim_{e.token}_{p.key}")
                    for p in e.params})
        kin_cfg = {"order": int(korder), "random_um": float(rnd_um),
                   "random_urad": float(rnd_urad)}
        p1, p2, p3, _p4 = st.columns(4)
        if p1.checkbox("Periodic X scale error", key="sim_periodic",
                       help="A sine wave along X (lead screw, rack): not in the default model, "
                            "so the diagnosis has to find it and its period. The 133 mm ball "
                            "pitch resolves no period under about 330 mm (2.5 pitches)."):
            per = int(p2.number_input("period (mm)", 20, 1200, 400, key="sim_per_mm"))
            amp = float(p3.number_input("amplitude (µm)", 0.0, 20.0, 1.0, key="sim_per_um"))
            kin_cfg.update(spec=f"kinematic21,periodic_x:{per}",
                           coefficients={f"dxx[sin{per}]": amp, f"dxx[cos{per}]": 0.0})
        if st.button("Simulate", key="simulate", type="primary"):

            cfg = {"seed": int(seed), "noise_um": float(noise), "order": order,
                   "probes_interleaved": bool(interleave),
                   "plate": {"form_um": float(form)},
                   "kinematic": kin_cfg,
                   "effects": eff}
            if layout != DEFAULT_LAYOUT:

                setup = thesis_machine_setup()
                setup["machine"]["layout"] = layout
                cfg["setup"] = setup
            sim = calls.safe(simulate, cfg, what="Simulation")
            inst = [] if sim is None or not sim_inst else calls.safe(
                _simulated_instruments, sim, int(seed), what="Simulating the instruments")
            if sim is not None:
                with tempfile.TemporaryDirectory() as tmp:
                    sim.write(tmp)
                    p = Path(tmp)
                    files = {"name": f"simulated (seed {int(seed)})"
                             + ("" if layout == DEFAULT_LAYOUT else f", {layout}"),
                             "kind": "simulated",
                             "setup_source": "the simulation's setup (thesis placements)",
                             "certificate_source": "the simulation's certificate",
                             "measurements": [("measurements.csv",
                                               (p / "measurements.csv").read_text())],
                             "setup": (p / "setup.json").read_text(),
                             "certificate": ("certificate.csv", (p / "certificate.csv").read_text())}
                ok = None if inst is None else calls.safe(state.set_dataset, files,
                                                      what="Loading the simulation")
                if ok is not None:
                    state.set_instruments(inst)
                    if inst:  # the simulation brings its own: "instrument files removed" misleads
                        st.session_state["reset_note"] = [
                            n for n in st.session_state.get("reset_note", [])
                            if "instrument file" not in n]
                    st.session_state["sim_truth"] = {"key": state.files_key(files),
                                                     "truth": sim.truth, "config": cfg}
                    _loaded("Simulated dataset loaded" + (
                        " with a laser run and a step gauge fitted jointly" if inst else "")
                        + ". The true parameters are on the Kinematic model page.")

with tab_proj:
    if tab_proj.open or widgets.held("up_project"):
        project_section()

# ---------------------------------------------------------------------------------------
# Instruments: laser runs and step gauges fitted jointly with the plate
# ---------------------------------------------------------------------------------------

def _read_instrument_uploads(uploads, have):
    """(kind, name, text) of every uploaded instrument file that reads, and the one-line
    problem of each that does not (the core reader's: file, row, column)."""
    new, errors = [], []
    names = {n for _, n, _ in have}
    for kind, files in uploads.items():
        for f in files or []:
            if f.name in names:
                errors.append(f"{f.name}: a file of this name is already loaded; remove it "
                              "first (the residual tables name instruments by file).")
                continue
            try:
                text = f.getvalue().decode("utf-8-sig")
                state.read_instrument_file(kind, f.name, text)
            except UnicodeDecodeError:
                errors.append(f"{f.name}: is not UTF-8 text; save it as UTF-8 CSV.")
            except Exception as exc:  # noqa: BLE001 - a message, never a traceback
                errors.append(calls.describe_error(exc))
            else:
                new.append((kind, f.name, text))
                names.add(f.name)
    if new and not errors:
        try:  # together, against this machine's strokes
            state.check_instruments(have + new)
        except Exception as exc:  # noqa: BLE001
            errors.append(calls.describe_error(exc))
    return new, errors


def instruments_section():
    """Instrument files fitted jointly with the plate, in an expander drawn only while open
    (its three file fields are the first screen's heaviest widgets, issue 27); it opens by
    itself when instruments are added, removed or refused."""
    s = st.session_state
    items = s.get("instruments") or []
    # opened once by new instruments or a new refusal, then as the user leaves it; the
    # label stays the same (a new label is a new expander, closed)
    now = (len(items), tuple(s.get("instrument_errors") or ()))
    if now != s.get("instruments_shown", (0, ())):
        s["w_instruments_open"] = True
    s["instruments_shown"] = now
    with st.expander("Instruments fitted jointly with the plate (laser, step gauge, ball bar)",
                     key="w_instruments_open", on_change="rerun") as box:
        if box.open:
            _instruments_body(s)
    if items and not box.open:
        st.caption(f"{len(items)} instrument file(s) in every fit: "
                   + ", ".join(n for _, n, _ in items) + ".")


def _instruments_body(s):
    kinds = list(A.instrument_kinds())
    st.write(f"Instrument files ({', '.join(state.INSTRUMENT_NAMES.get(k, k) for k in kinds)}) "
             "observe the machine's errors directly; their readings become rows of every "
             "fit, beside the plate's "
             "(docs/instruments.md). Machine axes, mm; errors and u in µm. Loading another "
             "dataset removes them (they measured the previous machine); a project file "
             "keeps them.")
    gen = s.get("inst_gen", 0)
    sfx = "" if gen == 0 else f"_{gen}"
    cols = st.columns(len(kinds))
    uploads = {}
    for col, kind in zip(cols, kinds, strict=True):
        uploads[kind] = col.file_uploader(
            f"{state.INSTRUMENT_NAMES.get(kind, kind).capitalize()} (CSV)", type=["csv", "txt"],
            accept_multiple_files=True, key=f"up_{kind}{sfx}", help=_instrument_columns(kind))
    if st.button("Add instrument files", key="add_instruments"):
        have = list(s.get("instruments") or [])
        new, errors = _read_instrument_uploads(uploads, have)
        s["instrument_errors"] = errors
        if not new and not errors:
            st.info("Choose instrument files above first.")
        elif not errors:
            state.set_instruments(have + new)
            s["inst_gen"] = gen + 1
            _loaded(f"Added {len(new)} instrument file(s): "
                    + ", ".join(n for _, n, _ in new) + ". Every fit now includes them.")
    for e in s.get("instrument_errors") or []:
        st.error(e)
    if s.get("instrument_errors"):
        st.caption("Nothing was added: the dataset and the instrument files loaded are "
                   "unchanged.")
    items = s.get("instruments") or []
    if not items:
        st.caption("No instrument files: the fits use the ball plate alone.")
        return
    data = calls.safe(cached.instrument_data, what="Reading the instrument files") or ()
    for i, (kind, name, _) in enumerate(items):
        c1, c2 = st.columns([5, 1])
        n = f", {len(data[i].rows)} readings" if i < len(data) else ""
        c1.markdown(f"**{name}**: {state.INSTRUMENT_NAMES.get(kind, kind)}{n}")
        c2.button("Remove", key=f"rm_instrument_{i}", on_click=state.remove_instrument,
                  args=(i,))


instruments_section()

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
        st.warning(f"{len(rep.outliers)} coordinate(s) flagged. They stay in the fit until you "
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
