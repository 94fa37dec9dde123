"""Refractive index of air by the modified Edlén equation (thesis §3.8, eq. 3.19).

Sources
-------
- K. P. Birch and M. J. Downs, "An updated Edlén equation for the refractive index of air",
  Metrologia 30 (1993) 155-162, and "Correction to the updated Edlén equation for the
  refractive index of air", Metrologia 31 (1994) 315-316 (the corrected water-vapour term
  used here).
- Saturation vapour pressure over water: IAPWS-IF97 region 4 saturation equation (Wagner et
  al., IAPWS 1997; the formula the NIST Engineering Metrology Toolbox "Refractive Index of
  Air Calculator", J. A. Stone and J. H. Zimmerman, uses, its appendix A-I).

The equation (t in °C, p in Pa, f partial pressure of water vapour in Pa, sigma the vacuum
wave number in µm⁻¹)::

    (n - 1)_s  = [8342.54 + 2406147 / (130 - sigma²) + 15998 / (38.9 - sigma²)] 1e-8
    (n - 1)_tp = p (n - 1)_s / 96095.43 * [1 + 1e-8 (0.601 - 0.00972 t) p] / (1 + 0.0036610 t)
    n_tpf      = n_tp - f (3.7345 - 0.0401 sigma²) 1e-10

for air with 450 µmol/mol CO2. Other CO2 fractions x are handled by scaling the dry-air
refractivity with Edlén's (1966) factor ``1 + 0.540 (x - 0.0003)`` relative to its value at
x = 0.00045 (a change of 100 µmol/mol moves n by about 1.5e-8).

Thesis eq. 3.19 is this equation with two simplifications, both written out here because the
thesis does not say so: (1) the water-vapour pressure is approximated as
``f ≈ RH · (8.753 + 0.036588 t²)`` Pa per %RH, i.e. a parabola for the saturation vapour
pressure, ``p_sv ≈ 875.3 + 3.6588 t²`` Pa (2338.8 Pa at 20 °C against 2339.2 Pa from
IAPWS; 3162 against 3170 Pa at 25 °C), so n differs from the full equation by about 1e-9
within 15-25 °C (see :func:`refractive_index_thesis_eq319`); (2) the water term is written
``0.037345 - 0.000401 sigma²`` in units of 1e-8, the same constants. The thesis calls sigma
"the vacuum wave number in mm⁻¹"; it must be in µm⁻¹.
"""

from __future__ import annotations

import math

# IAPWS-IF97, region 4 (saturation line), coefficients n1..n10.
_IF97 = (0.11670521452767e4, -0.72421316703206e6, -0.17073846940092e2, 0.12020824702470e5,
         -0.32325550322333e7, 0.14915108613530e2, -0.48232657361591e4, 0.40511340542057e6,
         -0.23855557567849, 0.65017534844798e3)

CO2_REFERENCE_PPM = 450.0
"""CO2 mole fraction (µmol/mol) of the Birch & Downs (1993) standard air."""


def _check(value, name, lo, hi, unit):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a number in {unit}, got {value!r}.") from None
    if not math.isfinite(v) or not lo <= v <= hi:
        raise ValueError(f"{name}: expected {lo} to {hi} {unit}, got {value!r}.")
    return v


def saturation_vapour_pressure_Pa(t_C: float) -> float:
    """Saturation vapour pressure over liquid water (IAPWS-IF97 region 4 equation).

    Parameters
    ----------
    t_C : float
        Temperature in °C (0 to 100 °C here; the equation covers 0.01 to 373.946 °C).

    Returns
    -------
    float
        p_sv in Pa.
    """
    t = _check(t_C, "t_C", 0.0, 100.0, "°C")
    n1, n2, n3, n4, n5, n6, n7, n8, n9, n10 = _IF97
    T = t + 273.15
    om = T + n9 / (T - n10)
    a = om * om + n1 * om + n2
    b = n3 * om * om + n4 * om + n5
    c = n6 * om * om + n7 * om + n8
    x = 2.0 * c / (-b + math.sqrt(b * b - 4.0 * a * c))
    return 1e6 * x**4


def refractive_index_edlen(t_C: float, p_Pa: float, rh_percent: float,
                           wavelength_nm: float = 632.99, co2_ppm: float = CO2_REFERENCE_PPM
                           ) -> float:
    """Refractive index of moist air, modified Edlén equation (Birch & Downs 1993, 1994).

    Parameters
    ----------
    t_C : float
        Air temperature, °C (0-40 accepted; the equation is validated for about 15-30 °C).
    p_Pa : float
        Air pressure, Pa (60 000-120 000).
    rh_percent : float
        Relative humidity, % (0-100); ``f = rh/100 · p_sv(t)`` with IAPWS-IF97 p_sv.
    wavelength_nm : float
        Vacuum wavelength, nm (350-1100). Default: He-Ne 632.99 nm.
    co2_ppm : float
        CO2 mole fraction, µmol/mol (default 450, the equation's reference).

    Returns
    -------
    float
        n (phase index).

    Notes
    -----
    Thesis eq. 3.19 approximates this equation (see the module docstring): the saturation
    vapour pressure is replaced by ``875.3 + 3.6588 t²`` Pa.
    """
    t = _check(t_C, "t_C", 0.0, 40.0, "°C")
    p = _check(p_Pa, "p_Pa", 60_000.0, 120_000.0, "Pa")
    rh = _check(rh_percent, "rh_percent", 0.0, 100.0, "%")
    lam = _check(wavelength_nm, "wavelength_nm", 350.0, 1100.0, "nm")
    x = _check(co2_ppm, "co2_ppm", 0.0, 2000.0, "µmol/mol")
    s2 = (1e3 / lam) ** 2                       # sigma² in µm⁻²
    ns = (8342.54 + 2406147.0 / (130.0 - s2) + 15998.0 / (38.9 - s2)) * 1e-8
    ns *= (1.0 + 0.540 * (x * 1e-6 - 0.0003)) / (1.0 + 0.540 * (CO2_REFERENCE_PPM * 1e-6 - 0.0003))
    ntp = p * ns / 96095.43 * (1.0 + 1e-8 * (0.601 - 0.00972 * t) * p) / (1.0 + 0.0036610 * t)
    f = rh / 100.0 * saturation_vapour_pressure_Pa(t)
    return 1.0 + ntp - f * (3.7345 - 0.0401 * s2) * 1e-10


def refractive_index_thesis_eq319(t_C: float, p_Pa: float, rh_percent: float,
                                  wavelength_nm: float = 632.99) -> float:
    """Thesis eq. 3.19 as printed (with sigma read in µm⁻¹), for comparison only."""
    t, p, r = float(t_C), float(p_Pa), float(rh_percent)
    s2 = (1e3 / float(wavelength_nm)) ** 2
    nm1_e8 = ((8342.54 + 2406147.0 / (130.0 - s2) + 15998.0 / (38.9 - s2)) * (p / 96095.43)
              * (1.0 + 1e-8 * (0.601 - 0.00972 * t) * p) / (1.0 + 0.0036610 * t)
              - r * (8.753 + 0.036588 * t * t) * (0.037345 - 0.000401 * s2))
    return 1.0 + nm1_e8 * 1e-8


def refractive_index_sensitivities(t_C: float, p_Pa: float, rh_percent: float,
                                   wavelength_nm: float = 632.99) -> dict[str, float]:
    """Partial derivatives of n (central differences): the a_i of thesis eq. 3.20-3.25.

    Returns ``{"dn_dt_per_K", "dn_dp_per_Pa", "dn_drh_per_percent"}`` (about -9.6e-7 /K,
    +2.7e-9 /Pa and -8.5e-9 /%RH at 20 °C, 101325 Pa, 50 %RH, 633 nm).
    """
    def n(t, p, r):
        return refractive_index_edlen(t, p, r, wavelength_nm)

    ht, hp, hr = 0.01, 1.0, 0.1
    rh_lo, rh_hi = max(rh_percent - hr, 0.0), min(rh_percent + hr, 100.0)
    return {
        "dn_dt_per_K": (n(t_C + ht, p_Pa, rh_percent) - n(t_C - ht, p_Pa, rh_percent)) / (2 * ht),
        "dn_dp_per_Pa": (n(t_C, p_Pa + hp, rh_percent) - n(t_C, p_Pa - hp, rh_percent)) / (2 * hp),
        "dn_drh_per_percent": (n(t_C, p_Pa, rh_hi) - n(t_C, p_Pa, rh_lo)) / (rh_hi - rh_lo),
    }


def air_from_args(t_C: float, p_Pa: float, rh_percent: float, wavelength_nm: float,
                  co2_ppm: float = CO2_REFERENCE_PPM) -> dict:
    """The ``air`` command (docs/formats.md): n by the modified Edlén equation, JSON-ready.

    Returns
    -------
    dict
        ``n``, ``n_minus_1``, ``wavelength_air_nm`` (= vacuum wavelength / n),
        ``p_sv_Pa``, ``f_Pa`` (water vapour partial pressure), the inputs, the
        sensitivities of n, ``n_thesis_eq319`` and ``method``.
    """
    n = refractive_index_edlen(t_C, p_Pa, rh_percent, wavelength_nm, co2_ppm)
    psv = saturation_vapour_pressure_Pa(t_C)
    return {
        "n": n,
        "n_minus_1": n - 1.0,
        "wavelength_vacuum_nm": float(wavelength_nm),
        "wavelength_air_nm": float(wavelength_nm) / n,
        "t_C": float(t_C), "p_Pa": float(p_Pa), "rh_percent": float(rh_percent),
        "co2_ppm": float(co2_ppm),
        "p_sv_Pa": psv,
        "f_Pa": float(rh_percent) / 100.0 * psv,
        "sensitivities": refractive_index_sensitivities(t_C, p_Pa, rh_percent, wavelength_nm),
        "n_thesis_eq319": refractive_index_thesis_eq319(t_C, p_Pa, rh_percent, wavelength_nm),
        "method": "modified Edlén equation (Birch & Downs 1993, corrected 1994); saturation "
                  "vapour pressure IAPWS-IF97",
    }

