"""Conformity of an interim check (issue 28): ISO 14253-1 statements, and a partial check
that cannot see part of the machine never says "conforms"."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from test_monitor import calibrated

from cmm_core.monitor import conformity, interim_check, remeasured, what_changed


def test_full_check_of_a_good_machine_conforms_to_a_loose_mpe():
    # the simulated machine's length errors reach 6.2 µm with U up to 1.8 µm (seed 5,
    # measured): 10 µm + L/100 leaves every length at least 2 µm inside its limit
    cal, model = calibrated("pitch80_3pos", 0)
    data = remeasured(cal, 5).dataset
    c = conformity(model, interim_check(model, data), data, mpe_a_um=10.0, mpe_per_mm=1 / 100)
    assert c.statement == "conforms", c.message
    assert c.counts["conforms"] == sum(c.counts.values()) > 0


def test_tight_mpe_does_not_conform_and_rule_is_stated():
    # 0.01 µm + L/1e6: micrometre errors exceed it beyond U for the long lengths
    cal, model = calibrated("pitch80_3pos", 0)
    data = remeasured(cal, 5).dataset
    c = conformity(model, interim_check(model, data), data, mpe_a_um=0.01, mpe_per_mm=1e-6)
    assert c.statement == "does not conform"
    assert "|E| + U <= MPE" in c.message


def test_one_placement_cannot_say_even_when_its_lengths_conform():
    cal, model = calibrated("pitch80_3pos", 0)
    first = str(cal.dataset.positions[0])
    data = remeasured(cal, 6, probes_per_position={
        first: cal.config["probes_per_position"][first]}).dataset
    c = conformity(model, interim_check(model, data), data, mpe_a_um=10.0, mpe_per_mm=1 / 100)
    assert c.counts["conforms"] == sum(c.counts.values()) > 0
    assert c.statement == "cannot say" and "cannot see" in c.message and c.unseen


def test_non_square_plate_cannot_say():
    cal, model = calibrated("pitch100_4pos", 0)  # 5 x 5: square; drop a row of balls
    data = remeasured(cal, 7).dataset
    cert = data.certificate
    keep = cert.balls <= 20
    data = replace(data, certificate=replace(cert, balls=cert.balls[keep],
                                             xyz_mm=cert.xyz_mm[keep], u_um=cert.u_um[keep]),
                   meas=data.meas[data.meas.ball <= 20])
    c = conformity(model, interim_check(model, data), data, mpe_a_um=5.0)
    assert c.statement == "cannot say" and "square" in c.message


def test_change_one_placement_cannot_see_is_told_so_not_conforms():
    # 20 µm of z scale (dzz[1]) with the plate flat at one height: the check cannot see
    # z lengths (it passes, p = 0.40 at this seed, measured), dzz[1] is not tested
    # (resolved < 10 %), and the machine is "cannot say", never "conforms"
    cal, model = calibrated("pitch100_4pos", 1)
    data = remeasured(cal, 41, probes_per_position={"H0": ["A", "B"]},
                      changes={"dzz[1]": 20.0}).dataset
    check = interim_check(model, data)
    ch = what_changed(model, check)
    row = ch.table.set_index("label").loc["dzz[1]"]
    assert not row.tested and row.resolved < 0.1
    c = conformity(model, check, data, mpe_a_um=10.0, mpe_per_mm=1 / 100, changes=ch)
    assert c.statement == "cannot say"


def test_a_ball_the_check_left_out_gives_no_length():
    """A ball measurement the check's fit excludes (a flagged blunder) is not counted in
    the conformity statement: a 50 µm blunder on it would otherwise fail every length to
    that ball. The 5 x 5 grid's pairs (``line_pairs``) through one ball: counted directly
    from the result, the difference to the full check equals them."""
    cal, model = calibrated("pitch80_3pos", 0)
    data = remeasured(cal, 5).dataset
    pos, prb, ball = data.meas.iloc[7][["position", "probe", "ball"]]
    meas = data.meas.copy()
    meas.loc[7, "mx_mm"] += 0.05  # a 50 µm blunder along X
    bad = replace(data, meas=meas)
    full = conformity(model, interim_check(model, data), data, mpe_a_um=10.0,
                      mpe_per_mm=1 / 100)
    kept = conformity(model, interim_check(model, bad, exclude=[(pos, prb, ball)]), bad,
                      mpe_a_um=10.0, mpe_per_mm=1 / 100)
    assert kept.statement == "conforms", kept.message
    assert "1 ball measurement(s) the check's fit left out" in kept.message
    m = full.mpe
    i = int(np.flatnonzero(data.certificate.balls == ball)[0]) + 1
    through = (m.position == f"{pos}/{prb}") & ((m.ball_a == i) | (m.ball_b == i))
    assert through.sum() > 0
    assert len(kept.mpe.error_um) == len(m.error_um) - through.sum()
    # with the blunder counted, the same limit is failed
    counted = conformity(model, interim_check(model, bad), bad, mpe_a_um=10.0,
                         mpe_per_mm=1 / 100)
    assert counted.counts.get("does not conform", 0) > 0
