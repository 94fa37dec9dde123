"""The self-contained HTML report: one function from an analysis record to one document.

:func:`analysis_report` (record -> HTML) is what the app's Export page and
``python -m cmm_core report`` both call, so the same record gives the same bytes (the
generation time aside). plotly.js is embedded once, deflate-compressed and decoded in the
browser (no network needed to open the report); each figure is a div with its data.
The figure builders live in :mod:`cmm_core.analysis.figures`.
"""

from __future__ import annotations

import functools
import html
import json
import re
import zlib
from collections.abc import Iterable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import plotly.graph_objects as go
import plotly.io as pio
from plotly.offline import get_plotlyjs, get_plotlyjs_version

from .. import __version__
from ..diagnosis import Diagnosis, Headline
from ..gum import MpeResult
from ..io import DataError, Dataset, atomic_write_text
from ..model import FitResult
from ..monitor import (
    CHANGE_RULE,
    HISTORY_RULE,
    TEST_RULE,
    VERDICTS,
    CheckOutcome,
    History,
    distinct_words,
    en_definition,
)
from ..units import p_text
from .figures import (
    fig_deviation,
    fig_en_map,
    fig_error_functions,
    fig_history,
    fig_mpe,
    fig_pattern,
    fig_placements,
)
from .record import ERROR_CONVENTION, AnalysisRecord
from .record_io import read_record, record_to_dict
from .residuals import instrument_tables, residual_summary
from .runner import AnalysisResult, run


def _table_html(df: pd.DataFrame, floatfmt="{:.4g}") -> str:
    # None in an object column (a value never computed) prints as "None" unless made NaN
    df = df.astype(object).where(df.notna(), np.nan).infer_objects()
    return df.to_html(index=False, border=0, classes="tbl", na_rep="—",
                      float_format=lambda v: floatfmt.format(v), escape=True)


_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,sans-serif;margin:2em auto;max-width:1200px;
color:#222;padding:0 1em}h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;
margin-top:1.6em}table.tbl{border-collapse:collapse;font-size:.85em;margin:.5em 0}
table.tbl td,table.tbl th{border:1px solid #ddd;padding:2px 6px;text-align:right}
.note{color:#555;font-size:.9em}.kv td{padding:2px 10px}
.chi2{padding:.4em .7em;border-left:4px solid #2ca02c;background:#f3faf3}
.chi2.fail{border-color:#d62728;background:#fdf1f1}
.headline{padding:.4em .7em;border-left:4px solid #1f77b4;background:#f1f6fc}
.headline.success{border-color:#2ca02c;background:#f3faf3}
.headline.warning{border-color:#ff7f0e;background:#fff6ec}
.headline.error{border-color:#d62728;background:#fdf1f1}
"""
TIMESTAMP = re.compile(r"Generated \d{4}-\d\d-\d\d \d\d:\d\d UTC")
"""The only part of a report that differs between two runs of the same record."""
_PLOTLY_CONFIG = json.dumps({"displaylogo": False, "responsive": True})
# base85 (Python's alphabet) with the characters HTML treats specially swapped for unused
# ones, so the payload can sit in a script element as it is
_ALPHABET = ("0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz"
             "!#$%:()*+-;,=.?@^_`{|}~")
_DIGITS = np.frombuffer(_ALPHABET.encode(), np.uint8)


def _pack(text: str) -> tuple[str, int]:
    """``text`` raw-deflated and base85-encoded, with the compressed length in bytes."""
    z = zlib.compressobj(9, zlib.DEFLATED, -15)
    data = z.compress(text.encode()) + z.flush()
    pad = -len(data) % 4
    a = np.frombuffer(data + b"\0" * pad, dtype=">u4").astype(np.int64)
    digits = np.empty((len(a), 5), np.uint8)
    for i in range(4, -1, -1):
        a, digits[:, i] = np.divmod(a, 85)
    out = _DIGITS[digits].tobytes()
    return out[:len(out) - pad].decode("ascii"), len(data)


@functools.lru_cache(maxsize=1)
def _plotly_packed() -> tuple[str, int]:
    """plotly.js packed (1.8 MB instead of 4.8), once per process."""
    return _pack(get_plotlyjs())


def plotly_loader(figures: dict) -> str:
    """The one copy of plotly.js and the figures' data, packed, and the script that
    unpacks them: the promise ``cmmPlotlyReady`` resolves to ``{div id: figure}``."""
    js, n_js = _plotly_packed()
    figs, n_figs = _pack("{" + ",".join(f'"{k}":{v}' for k, v in figures.items()) + "}")
    return (f"<script id='cmm-plotly' type='application/octet-stream'>{js}</script>\n"
            f"<script id='cmm-figures' type='application/octet-stream'>{figs}</script>\n"
            f"<script>/* plotly.js v{get_plotlyjs_version()} and the figures, inline: raw "
            "deflate, base85 */\nwindow.cmmPlotlyReady=(function(){"
            f'var A="{_ALPHABET}",M=new Uint8Array(128),i;'
            "for(i=0;i<85;i++)M[A.charCodeAt(i)]=i;function unpack(id,n){var i,j,v,k=0,"
            "s=document.getElementById(id).textContent.trim(),"
            "o=new Uint8Array(Math.ceil(s.length/5)*4);"
            "for(i=0;i<s.length;i+=5){v=0;for(j=0;j<5;j++)v=v*85+(i+j<s.length?"
            "M[s.charCodeAt(i+j)]:84);o[k++]=v>>>24;o[k++]=v>>>16&255;o[k++]=v>>>8&255;"
            "o[k++]=v&255;}return new Response(new Blob([o.subarray(0,n)]).stream()"
            ".pipeThrough(new DecompressionStream('deflate-raw'))).text();}"
            f"return Promise.all([unpack('cmm-plotly',{n_js}),unpack('cmm-figures',{n_figs})])"
            ".then(function(t){var e=document.createElement('script');e.textContent=t[0];"
            "document.head.appendChild(e);return JSON.parse(t[1]);});})();\n"
            "cmmPlotlyReady.catch(function(){document.body.insertAdjacentHTML('afterbegin',"
            "\"<p class='chi2 fail'>The figures need a browser from 2023 or later "
            "(DecompressionStream); the tables are complete.</p>\");});</script>")


def figure_html(fig: go.Figure, div_id: str, figures: dict) -> str:
    """A figure's div and the script that draws it once unpacked; its data go into
    ``figures`` (packed by :func:`plotly_loader`)."""
    figures[div_id] = pio.to_json(fig, validate=False, remove_uids=True)
    height = fig.layout.height or 450
    return (f"<div id='{div_id}' class='plotly-graph-div' style='height:{height}px;"
            f"width:100%'></div><script>cmmPlotlyReady.then(function(F){{Plotly.newPlot("
            f"'{div_id}',F['{div_id}'].data,F['{div_id}'].layout,{_PLOTLY_CONFIG});}});"
            "</script>")


def chi2_test_numbers(r: FitResult) -> tuple:
    """``(χ²/dof, dof, note)`` of the fit's χ² test. With the certificate fixed the test
    counts its calibration uncertainty (``FitResult.chi2_test``); the note then says so,
    with the fit's own χ²/dof."""
    if not r.test_counts_certificate:
        return r.chi2_dof, r.dof, ""
    return r.chi2_test_dof, r.test_statistic[1], (f" (the certificate's calibration uncertainty counted; the fit's own "
                      f"χ²/dof is {r.chi2_dof:.2f})")


def chi2_html(result: FitResult) -> str:
    """The fit's χ² test in words, shown next to every uncertainty: when it fails, by how
    much the σ-based values understate the scatter (Birge ratio)."""
    r = result
    val, dof, note = (html.escape(str(x)) if isinstance(x, str) else x
                      for x in chi2_test_numbers(r))
    if r.fails_chi2_test:
        return (f"<p class='chi2 fail'><b>The model fails its χ² test</b>: χ²/dof "
                f"{val:.2f} at {dof} degrees of freedom ({p_text(r.chi2_p_value)}){note}. "
                f"Uncertainties from σ = {r.sigma_um:.3g} µm alone are too small by the "
                f"Birge ratio ×{r.birge_ratio:.2f}; the inflated values are shown beside "
                "them. Neither is trustworthy until the diagnosis explains the misfit.</p>")
    return (f"<p class='chi2'>χ² test passed: χ²/dof {val:.2f} at {dof} degrees of "
            f"freedom ({p_text(r.chi2_p_value)}){note}; the σ-based uncertainties stand.</p>")


def _uncertainty_table(uncertainty, result) -> pd.DataFrame:
    rows = []
    for lab in ("U1_um", "U2_um", "U3_um"):
        val = getattr(uncertainty, lab, None)
        row = {"quantity": lab[:2], **({f"{a} (µm)": val[a] for a in "xyz"} if val else {})}
        if val and result.fails_chi2_test:  # noise part scaled, certificate's as it is
            vi = uncertainty.inflated[lab]
            row.update({f"{a} × Birge (µm)": vi[a] for a in "xyz"})
        rows.append(row)
    return pd.DataFrame(rows)


def _record_sections(res) -> list:
    """(heading, html) sections an :class:`~cmm_core.analysis.AnalysisResult` adds:
    sources and settings, σ, outliers, measured errors, the instruments, the GP."""

    rec, r = res.record, res.fit
    d = rec.data
    files = [("measurements", f) for f in d.measurements] + [("setup", d.setup)] + (
        [("certificate", d.certificate)] if d.certificate else []) + [
        (i.kind, i.file) for i in d.instruments]
    prov = d.provenance()
    digests = [(role, f.digest()) for role, f in files]
    src = pd.DataFrame([{"role": role, "file": f.name, "SHA-256": g.sha256 if g else
                         "(not readable)", "bytes": g.n_bytes if g else None}
                        for (role, f), (_, g) in zip(files, digests, strict=True)])
    settings = {k: v for k, v in record_to_dict(rec).items()
                if k not in ("data", "history", "provenance")}
    rows = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(json.dumps(v))}</td></tr>"
                   for k, v in settings.items())
    made = [("Software", prov.code), ("Python and system", f"{prov.python}, {prov.system}"),
            ("Machine", prov.machine or "not named (setup key machine.id)"),
            ("Calibration date", prov.calibration_date or "not stated (setup key "
             "calibration_date)")]
    made_rows = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>"
                        for k, v in made)
    out = [("Provenance", "<p class='note'>What made this report, from which files (each "
            "identified by the SHA-256 of its content) and for which machine.</p>"
            f"<table class='kv' id='provenance'>{made_rows}</table>" + _table_html(src)),
           ("Analysis record", "<p class='note'>The same record (ANALYSIS.json, "
            "<code>cmm-error-lab report</code>) gives the same numbers and this same "
            f"report.</p><table class='kv'>{rows}</table>")]
    t = r.table
    err = pd.DataFrame(np.column_stack([res.measured_error_um, r.residuals_um]),
                       columns=[f"{k} {a} (µm)" for k in ("error", "residual") for a in "xyz"])
    err.insert(0, "position", t["position"].to_numpy())
    rms = err.groupby("position", sort=False).agg(lambda v: float(np.sqrt(np.mean(v ** 2))))
    out.append(("Measured error and what the model leaves (RMS per position)",
                f"<p class='note'>Sign: {html.escape(ERROR_CONVENTION)}. Measured error from "
                "the placements alone (no error model); residual: corrected measurement "
                "minus placed ball.</p>" + _table_html(rms.reset_index())))
    flagged = ", ".join(f"{p}/{q} ball {b}" for p, q, b in res.flagged) or "none"
    out.append(("Outliers", f"<p>Flagged by the robust check: {html.escape(flagged)}. "
                + ("Excluded (exclude_outliers is true)." if rec.exclude_outliers else
                   "Kept in the fit unless excluded by name (exclude_outliers is false).")
                + "</p>"))
    if res.instruments:
        table, readings = instrument_tables(res.instruments, res.instrument_residuals)
        out.append(("Instruments fitted with the plate", "<p class='note'>Laser runs, "
                    "step gauges and ball bars (docs/instruments.md) are rows of the same fit. Residual: "
                    "the model's prediction minus the reading (µm), the runs' zeros and "
                    "slopes removed; RMS residual/u near 1 when the model explains the "
                    "instrument as its u says.</p>" + _table_html(table)
                    + _table_html(readings, "{:.4f}")))
    if res.gp is not None:
        gp = pd.json_normalize([{"component": c, **v} for c, v in res.gp.summary().items()])
        gp["LOO coverage 95 %"] = gp["component"].map(res.gp.loo_coverage(0.95))
        out.append((f"Gaussian process of the measured error ({rec.gp_mean} mean, "
                    f"{rec.gp_kernel})", _table_html(gp)))
    return out


def analysis_report(record: AnalysisRecord, *, generated: str | None = None) -> str:
    """The HTML report of an analysis record: what the Export page and ``python -m
    cmm_core report`` both call (``generated``: the time printed, default now)."""

    return render(run(record), generated=generated)


def write_report(analysis_path: str | Path, out_path: str | Path, *,
                 confine: bool = True) -> dict:
    """``python -m cmm_core report``: the report of the record at ``analysis_path``
    written to ``out_path``; returns what the command prints (the fit's χ² test too).
    ``confine``: the record's files must lie in its folder (:func:`read_record`)."""
    if not Path(out_path).parent.is_dir():  # refused before minutes of work, not after
        raise DataError(f"the folder {Path(out_path).parent} does not exist.",
                        file=Path(out_path).name, hint="create it or write elsewhere.")
    res = run(read_record(Path(analysis_path), confine=confine))
    text = render(res)
    atomic_write_text(out_path, text)  # temporary file + rename: never half a report
    return {"out": str(out_path), "bytes": len(text.encode()), **res.fit.summary(),
            "sigma": res.sigma,
            "excluded": [list(e) for e in res.exclusions],
            "flagged_outliers": [list(e) for e in res.flagged],
            **({} if res.interim is None else {"interim_check": {
                "verdict": res.interim.verdict, "chi2": res.interim.check.chi2,
                "dof": res.interim.check.dof, "p_value": res.interim.check.p_value,
                "new_effects": [] if res.interim.effects is None else
                [e["effect"] for e in res.interim.effects.named if e["confirmed"]]}}),
            **({} if res.calibration_history is None else {"history": {
                "significant": list(res.calibration_history.significant)}})}


def render(res: AnalysisResult, *, generated: str | None = None) -> str:
    """The HTML report of an :class:`~cmm_core.analysis.AnalysisResult`."""
    diag, text, head = None, "", None
    if res.diagnosis is not None:
        diag = pd.DataFrame(diagnosis_rows(res.diagnosis))
        text = diagnosis_conclusion(res.diagnosis)
        head = res.diagnosis.headline()
    figs: dict[str, str] = {}
    sections = _record_sections(res) + monitor_sections(res.interim, res.calibration_history,
                                                        figs)
    return build_report(res.dataset, res.fit, exclusions=res.exclusions,
                        history=list(res.history), uncertainty=res.uncertainty,
                        diagnosis=diag, magnification=res.record.magnification,
                        diagnosis_conclusion=text, diagnosis_headline=head, mpe=res.mpe,
                        generated=generated, sigma=res.sigma, extra_sections=sections,
                        extra_figures=figs)


def _esc(text: str) -> str:
    return html.escape(str(text))


def monitor_sections(interim: CheckOutcome | None, hist: History | None,
                     figures: dict) -> list:
    """The report's sections "Interim check" and "History" (docs/monitoring.md): the
    test with its decision rule, the E_n map (:func:`.figures.fig_en_map`, E_n at the
    check's coverage factor, stated: ISO/IEC 17043:2010 Annex B), what changed with the
    uncertainties, the new effect the diagnosis names, what the check cannot see in
    words, conformity; the history's changes with u and E_n, a trend plot, the error
    map's change. Figures go into ``figures`` (ids ``mon1``, ``mon2`` ...)."""
    out = []

    def fig(f: go.Figure) -> str:
        return figure_html(f, f"mon{len(figures) + 1}", figures)

    if interim is not None:
        c, ch = interim.check, interim.changes
        en = f"E_n (k = {c.coverage_factor:g})"
        ok = interim.verdict == VERDICTS[0]
        kv = [("Stored calibration", c.model_name), ("Verdict", interim.verdict),
              ("χ²", f"{c.chi2:.2f}"), ("Degrees of freedom", str(c.dof)),
              ("p-value", f"{c.p_value:.3g}"), ("Level α", f"{c.alpha:g}"),
              ("σ of the new data", f"{c.sigma_um:g} µm"),
              ("Ball centres", str(len(c.table))),
              ("Placements", ", ".join(map(str, c.positions)) or "none"),
              ("Within their 95 % intervals", f"{100 * c.coverage_95:.1f} %"),
              ("Coverage factor of the E_n", f"k = {c.coverage_factor:g}")]
        rows = "".join(f"<tr><th>{_esc(k)}</th><td>{_esc(v)}</td></tr>" for k, v in kv)
        body = [f"<p class='chi2{'' if ok else ' fail'}'><b>{_esc(interim.verdict)}</b>: "
                f"{_esc(interim.message)}</p>", f"<table class='kv'>{rows}</table>",
                f"<p>{_esc(c.message)}</p>",
                f"<p class='note'>Decision rule: {_esc(TEST_RULE)}. "
                f"{_esc(en_definition(c.coverage_factor))}.</p>"]
        if len(c.table):
            body.append(fig(fig_en_map(
                c.table, f"Normalised errors of the new observations: {en}, the largest "
                         "of x, y, z at each place (scale readings)", height=450,
                coverage_factor=c.coverage_factor)))
            cols = ["position", "probe", "ball", "dx_um", "dy_um", "dz_um", "u_dx_um",
                    "u_dy_um", "u_dz_um", "En_x", "En_y", "En_z"]
            body.append(f"<p class='note'>The 10 largest |{en}| (residual: measured minus "
                        "predicted after the pose fit, µm; u: its standard uncertainty "
                        "with the stored model's, the certificate's and σ; En_x ...: "
                        f"residual / ({c.coverage_factor:g} u)).</p>"
                        + _table_html(c.largest_En(10)[cols]))
        if len(c.instruments):
            r = c.readings
            body.append(_table_html(c.instruments)
                        + f"<p class='note'>The instrument readings of largest |{en}| (file "
                          "row; residual: the stored model's prediction minus the reading, "
                          "the run's offset and slope removed, µm; u: its standard "
                          "uncertainty).</p>"
                        + _table_html(r.loc[r["En"].abs().nlargest(min(10, len(r))).index]))
        tested = ch.table[ch.table["tested"]]
        body.append(f"<h3>What changed</h3><p>{_esc(ch.message)}</p>" + _table_html(
            tested[["label", "unit", "stored", "change", "u_updated", "u_null", "En",
                    "significant",
                    "change_alone", "u_change_alone", "En_alone", "significant_alone",
                    "resolved"]])
            + "<p class='note'>change: the posterior mean of the change (shrunk toward 0 "
              "by about its resolved fraction); u_updated: its standard uncertainty (the "
              "posterior sd); u_null: the sd of the change if nothing changed; En: "
              f"change / ({ch.coverage_factor:g} u_null), {_esc(en)}; change_alone: the "
              "unshrunk change had the parameter alone moved, En_alone its E_n at the "
              f"same k. Decision rule: {_esc(CHANGE_RULE)}.</p>")
        if interim.effects is not None:
            body.append(f"<h3>New effect (the diagnosis against the stored model)</h3><p>"
                        f"{_esc(interim.effects.message)}</p>")
            if interim.effects.named:
                body.append(_table_html(pd.DataFrame([
                    {"effect": e["effect"], "title": e["title"],
                     "size": "; ".join(f"{k} {v['value']:+.3g} ± {v['u']:.2g} {v['unit']}"
                                       for k, v in e["fitted"].items()),
                     "p_value": e["p_value"], "confirmed": e["confirmed"]}
                    for e in interim.effects.named])))
        unseen = ch.unseen
        body.append("<h3>What this check cannot see</h3>" + (
            f"<p>{len(unseen)} combination(s) of the stored model's parameters (a change "
            "there passes unnoticed):</p><ul>" + "".join(
                f"<li>{_esc(u)}" + (f" ({n} combinations)" if n > 1 else "") + "</li>"
                for u, n in distinct_words(unseen)) + "</ul>"
            + "<p class='note'>One basis of what the new data cannot determine, each named "
              "by the errors that carry it (the combinations themselves, as weights in "
              "units of each parameter's prior u, are the results document's "
              "interim_check.changes.unseen_combinations).</p>"
            if unseen else "<p>Nothing: the new data resolve every combination of the "
                           "stored model's parameters.</p>"))
        if interim.conformity is not None:
            cf = interim.conformity
            body.append(f"<h3>Conformity</h3><p><b>{_esc(cf.statement)}</b>: "
                        f"{_esc(cf.message)}</p>")
        out.append(("Interim check", "".join(body)))
    if hist is not None:
        body = [f"<p>{_esc(hist.message)}</p>",
                "<p class='note'>Calibrations: " + _esc(", ".join(
                    f"{n} ({d})" for n, d in zip(hist.names, hist.dates, strict=True)))
                + f". Decision rule: {_esc(HISTORY_RULE)}.</p>"]
        chg = hist.changes
        sig = list(dict.fromkeys(chg.loc[chg["significant"], "label"]))
        shown = sig or list(dict.fromkeys(hist.trend["label"]))[:4]
        f = go.Figure()
        for lab in shown:
            tr = hist.trend[hist.trend["label"] == lab]
            f.add_trace(go.Scatter(x=tr["date"], y=tr["value"], name=lab,
                                   mode="lines+markers",
                                   error_y={"type": "data", "array": tr["u"]}))
        f.update_layout(title=("Significant changes" if sig else "Parameters") +
                        " over the calibrations (± u)", xaxis_title="date",
                        yaxis_title="value (µm or µrad)", height=400)
        body.append(fig(f))
        body.append(_table_html(chg) + "<p class='note'>u_change: sqrt(u₁² + u₂²); En: "
                    f"change / ({hist.coverage_factor:g} u_change), E_n (k = "
                    f"{hist.coverage_factor:g}); p_value: two-sided, of change / "
                    "u_change.</p>")
        d = hist.map_change
        body.append("<p class='note'>The error map's change, first to last calibration, "
                    "over the working volume (ram reference point): largest |change| and "
                    "largest standard uncertainty per component (µm).</p>" + _table_html(
                        pd.DataFrame([{"component": a,
                                       "largest |change| (µm)": float(np.abs(
                                           d[f"de{a}_um"]).max()),
                                       "largest u (µm)": float(d[f"u_de{a}_um"].max())}
                                      for a in "xyz"])))
        out.append(("History", "".join(body)))
    return out


def diagnosis_rows(d: Diagnosis) -> list:
    """The diagnosis's candidates as report rows (best first)."""
    cols = ("effect", "title", "rms_um", "chi2_dof", "delta_chi2", "n_params", "delta_bic",
            "p_value")
    return [{**{k: c.to_dict()[k] for k in cols}, "significant": bool(c.significant),
             "aliases": ", ".join(c.aliases)} for c in d.candidates]


def headline_html(h: Headline) -> str:
    """The diagnosis's headline (``Diagnosis.headline``, the app's first message) as a
    box of its level: the title in bold, the text, the action."""
    return (f"<div class='headline {_esc(h.level)}'><p><b>{_esc(h.title)}</b></p>"
            f"<p>{_esc(h.text)}</p><p>Next: {_esc(h.action)}</p></div>")


def diagnosis_conclusion(d: Diagnosis) -> str:
    """The diagnosis's verdict in words, with the candidates it did not try."""
    return d.message + "".join(f" Not tried: {k} ({v})." for k, v in d.skipped.items())


def build_report(dataset: Dataset, result: FitResult, *, exclusions: Iterable = (),
                 history: Iterable = (), uncertainty: Any = None,
                 diagnosis: pd.DataFrame | None = None, magnification: float = 2000.0,
                 extra_sections: Iterable = (), diagnosis_conclusion: str = "",
                 diagnosis_headline: Headline | None = None, mpe: MpeResult | None = None,
                 generated: str | None = None, sigma: dict | None = None,
                 extra_figures: dict | None = None) -> str:
    """A self-contained HTML report of a fit: summary, figures and tables.

    Prefer :func:`analysis_report`, which builds every argument from one analysis record.

    Parameters
    ----------
    dataset : Dataset
    result : FitResult
    exclusions : iterable of (position, probe, ball)
    history : list of dict
        Diagnosis history rows (spec, change, rms_um, chi2_dof, bic, gp_amplitude_um).
    uncertainty : UncertaintySummary, optional
    diagnosis : DataFrame, optional
        Ranked candidate effects.
    magnification : float
        Magnification of the deviation plots.
    extra_sections : iterable of (heading, html) pairs, optional
    diagnosis_conclusion : str
        The diagnosis's plain-language verdict, printed above its table.
    diagnosis_headline : Headline, optional
        The diagnosis's headline (``Diagnosis.headline``), shown first in its section (the
        app's Diagnose page and ``diagnose --json`` carry the same).
    mpe : MpeResult, optional
        The MPE check (``cmm_core.gum.mpe.mpe_check``): plot, counts and the rule used.
    generated : str, optional
        Generation time printed (default: now, UTC, to the minute).
    sigma : dict, optional
        How σ was chosen (``{"auto": bool, ...}``, :func:`cmm_core.analysis.run`).
    extra_figures : dict, optional
        The figures of ``extra_sections`` (div id -> figure JSON, :func:`figure_html`),
        packed with the report's own.

    Returns
    -------
    str
        One HTML document; plotly.js is embedded once, compressed (no network needed).
    """
    parts: list[str] = []
    figures: dict[str, str] = dict(extra_figures or {})

    def fig_html(fig):
        return figure_html(fig, f"fig{len(figures) + 1}", figures)

    def section(title, *items):
        parts.append(f"<h2>{html.escape(title)}</h2>")
        parts.extend(items)

    now = generated or datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    r = result
    val, dof, _ = chi2_test_numbers(r)
    chi2 = (f"{'FAILS' if r.fails_chi2_test else 'passes'} at 1 %: χ²/dof {val:.3f}, "
            f"{dof} dof, {p_text(r.chi2_p_value)}")
    summary = [("Dataset", dataset.name), ("Positions", ", ".join(map(str, dataset.positions))),
               ("Probes", ", ".join(map(str, dataset.probes))),
               ("Certificate", "yes" if dataset.certificate is not None else
                "none (plate self-calibrated)"),
               ("Setup frame", dataset.setup.frame),
               ("Model", r.spec), ("Plate geometry", r.plate),
               ("Certificate uncertainty", r.certificate_u_source),
               ("Repeatability σ", f"{r.sigma_um:g} µm" + (
                   " (estimated from the data)" if sigma and sigma.get("auto") else "")),
               ("Observations", str(r.n_obs)), ("Status", r.status),
               ("RMS of residuals", f"{r.rms_um:.3f} µm"),
               ("χ²/dof of the fit", f"{r.chi2_dof:.3f} ({r.dof} dof)"),
               ("χ² test", chi2), ("Birge ratio √(χ²/dof)", f"{r.birge_ratio:.3f}"),
               ("BIC", f"{r.bic:.1f}"), ("Effective parameters (rank)", str(r.rank)),
               ("Excluded observations", "; ".join(f"{p}/{q} ball {b}"
                                                   for p, q, b in exclusions) or "none")]
    rows = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(str(v))}</td></tr>"
                   for k, v in summary)
    parts.append(f"<h1>CMM error lab report</h1><p class='note'>Generated {now} by cmm-error-lab "
                 f"{__version__}. Lengths in mm, errors and uncertainties in µm (rotations "
                 "µrad); bands and expanded uncertainties at k = 2.</p>")
    section("Summary", f"<table class='kv'>{rows}</table>", chi2_html(r),
            f"<p>{html.escape(r.message)}</p>")
    if r.unidentifiable:
        section("Identifiability",
                "<p>The data cannot determine these parameter combinations:</p><ul>"
                + "".join(f"<li>{html.escape(w)} <span class='note'>({html.escape(c)})</span>"
                          "</li>" for w, c in zip(r.null_words, r.null_combinations,
                                                  strict=True))
                + "</ul>")
    section("Plate placements", fig_html(fig_placements(dataset)))
    section("Fitted error functions", chi2_html(r), fig_html(fig_error_functions(r)))
    for pos in r.problem.obs.positions:
        section(f"Deviations, {pos}", fig_html(fig_deviation(r, pos, magnification)))
    section("Residuals", fig_html(fig_pattern(r.table, r.residuals_um,
                                              "Residuals per observation (µm)")),
            _table_html(residual_summary(r)))
    if uncertainty is not None:
        section("Uncertainty (standard, k = 1; thesis tables 4.1-4.3)", chi2_html(r),
                _table_html(_uncertainty_table(uncertainty, r)),
                f"<p class='note'>{html.escape(uncertainty.message)}</p>")
    ranked = diagnosis is not None and len(diagnosis) > 0
    if ranked or diagnosis_headline is not None:
        items = ["" if diagnosis_headline is None else headline_html(diagnosis_headline),
                 f"<p>{html.escape(diagnosis_conclusion)}</p>" if diagnosis_conclusion else ""]
        if diagnosis is not None and ranked:
            keep = [c for c in ("effect", "title", "rms_um", "chi2_dof", "delta_chi2",
                                "n_params", "delta_bic", "p_value", "significant", "aliases")
                    if c in diagnosis]
            items += [_table_html(diagnosis[keep].head(10) if keep else diagnosis.head(10)),
                      f"<p class='note'>The 10 best of {len(diagnosis)} candidates.</p>"]
        section("Diagnosis: candidate effects, best first", *items)
    if mpe is not None:
        counts = pd.DataFrame([{"decision": k, "lengths": v} for k, v in mpe.counts.items()])
        section("MPE check (0.6 µm + L/600 with L in mm, ISO 14253-1 decision rule)", chi2_html(r),
                fig_html(fig_mpe(mpe)), _table_html(counts),
                "<p class='note'>Conforms when |E| + U ≤ MPE, does not conform when |E| − U "
                "> MPE, otherwise inconclusive; U (k = 2) from the record's MPE uncertainty source "
                "(mpe_u_source; by default the test's: plate certificate and repeatability).</p>")
    if history:
        hist = pd.DataFrame(history)
        section("Diagnosis history", fig_html(fig_history(list(history))), _table_html(hist))
    pf = r.parameters_frame()
    if r.fails_chi2_test:
        pf["u × Birge"] = r.u_inflated
    pf["identifiable"] = ~pf["parameter"].isin(r.unidentifiable)
    if "unit" in pf:
        pf["unit"] = pf["unit"].map(lambda u: str(u).replace("urad", "µrad").replace(
            "um", "µm"))
    section("Fitted parameters (value and standard uncertainty)", chi2_html(r),
            _table_html(pf))
    for heading, body in extra_sections:
        section(heading, body)
    return ("<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<title>CMM error lab report</title><style>{_CSS}</style></head><body>"
            + plotly_loader(figures) + "\n" + "\n".join(parts) + "</body></html>")
