#!/usr/bin/env python3
"""Reference values for photon band radiance and band-radiance temperature derivatives.

Writes tests/data/planck_photon_table.csv: for each temperature and band, the blackbody photon radiance
∫ B_λ λ/(hc) dλ (photons s⁻¹ m⁻² sr⁻¹) and the temperature derivatives dL/dT of the energy radiance
(W m⁻² sr⁻¹ K⁻¹) and of the photon radiance (photons s⁻¹ m⁻² sr⁻¹ K⁻¹), computed by mpmath quadrature at
40 significant digits with CODATA 2018 constants, independently of the Rust implementation.

Run from the repository root:  python3 tools/planck_photon_reference.py
"""
import csv
import mpmath as mp

mp.mp.dps = 40
h = mp.mpf("6.62607015e-34")
c = mp.mpf("299792458")
k = mp.mpf("1.380649e-23")


def photon(lam_m, t):
    x = h * c / (lam_m * k * t)
    return 2 * c / lam_m**4 / mp.expm1(x)


def energy(lam_m, t):
    x = h * c / (lam_m * k * t)
    return 2 * h * c**2 / lam_m**5 / mp.expm1(x)


def d_dt(f, lam_m, t):
    # analytic derivative of the spectral quantity with respect to T: f · x eˣ/(eˣ − 1) / T
    x = h * c / (lam_m * k * t)
    return f(lam_m, t) * x * mp.exp(x) / mp.expm1(x) / t


def band(f, lo_um, hi_um, t):
    a, b = mp.mpf(lo_um) * mp.mpf("1e-6"), mp.mpf(hi_um) * mp.mpf("1e-6")
    pts = mp.linspace(a, b, 9)
    return mp.quad(lambda lam: f(lam, t), pts)


rows = []
for t in ["50", "150", "220", "250", "288.15", "300", "350", "500", "1000", "5772"]:
    T = mp.mpf(t)
    for lo, hi in [("3", "5"), ("3.7", "4.8"), ("7.5", "13.5"), ("8", "12"), ("8", "14"), ("1", "3"), ("10", "10.5")]:
        lq = band(photon, lo, hi, T)
        dle = band(lambda lam, tt: d_dt(energy, lam, tt), lo, hi, T)
        dlq = band(lambda lam, tt: d_dt(photon, lam, tt), lo, hi, T)
        rows.append([t, lo, hi, mp.nstr(lq, 20), mp.nstr(dle, 20), mp.nstr(dlq, 20)])

with open("tests/data/planck_photon_table.csv", "w", newline="") as f:
    w = csv.writer(f)
    w.writerow(["T_K", "lam1_um", "lam2_um", "Lq_photons_s_m2_sr", "dL_dT_W_m2_sr_K", "dLq_dT_photons_s_m2_sr_K"])
    w.writerows(rows)
print(f"wrote {len(rows)} rows")
