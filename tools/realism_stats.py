#!/usr/bin/env python3
"""Frame statistics of a recorded irsim sequence, computed the way they are for real infrared sky imagery.

Usage: tools/realism_stats.py OUT_DIR [OUT_DIR ...]

Per sequence (medians over frames): the frame's standard deviation (DN), the temporal noise σ (from the
difference of consecutive frames, σ = 1.4826·MAD(f_k − f_{k−1})/√2, so that neither the scene nor its edges
moving with the camera count), their ratio, the
radially averaged power-spectrum slope of the frame (plane removed, Hann window, fitted over 8/n … 0.25
cycles/px), the share of rows that are one constant value (a black band), and per target the label SNR and SCR
(medians over the frames where it is in the frame) and the fraction of frames where it is in the frame and
detectable. Needs numpy and pillow.
"""
import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image


def robust_sigma(d):
    """σ from the median absolute deviation: scene edges that moved between frames fall in the tails."""
    return 1.4826 * np.median(np.abs(d - np.median(d)))


def psd_slope(img):
    h, w = img.shape
    y, x = np.mgrid[0:h, 0:w]
    a = np.c_[x.ravel(), y.ravel(), np.ones(x.size)]
    coef, *_ = np.linalg.lstsq(a, img.ravel(), rcond=None)
    d = img - (a @ coef).reshape(h, w)
    win = np.outer(np.hanning(h), np.hanning(w))
    p = np.abs(np.fft.fft2(d * win)) ** 2
    fy = np.fft.fftfreq(h)[:, None]
    fx = np.fft.fftfreq(w)[None, :]
    f = np.hypot(fx, fy)
    n = min(h, w)
    edges = np.geomspace(8.0 / n, 0.25, 16)
    fs, ps = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (f >= lo) & (f < hi)
        if m.any():
            fs.append(np.sqrt(lo * hi))
            ps.append(p[m].mean())
    slope, _ = np.polyfit(np.log(fs), np.log(ps), 1)
    return slope


def main():
    for out in map(Path, sys.argv[1:]):
        frames = sorted((out / "frames").glob("*.png"))
        imgs = [np.asarray(Image.open(f), dtype=np.float64) for f in frames]
        stds = [im.std() for im in imgs]
        noise = [robust_sigma(b - a) / np.sqrt(2) for a, b in zip(imgs, imgs[1:])]
        slopes = [psd_slope(im) for im in imgs[:: max(1, len(imgs) // 5)]]
        flat_rows = np.mean([np.mean(im.std(axis=1) == 0) for im in imgs])
        labels = [json.loads(l) for l in (out / "labels.jsonl").read_text().splitlines()]
        per = {}
        for lab in labels:
            for t in lab["targets"]:
                d = per.setdefault(t["name"], {"snr": [], "scr": [], "in": 0, "det": 0, "n": 0})
                d["n"] += 1
                if t["in_frame"]:
                    d["in"] += 1
                    d["snr"].append(t["snr"])
                    d["scr"].append(t["scr"])
                    d["det"] += t["detectable"]
        print(f"{out}: {len(imgs)} frames {imgs[0].shape[1]}×{imgs[0].shape[0]}")
        sd, nz = np.median(stds), np.median(noise) if noise else float("nan")
        print(f"  frame std {sd:.1f} DN, temporal noise {nz:.2f} DN, noise/std {nz / sd:.3f}, "
              f"PSD slope {np.median(slopes):.2f}, constant rows {flat_rows:.3f}")
        for name, d in per.items():
            snr = np.median(d["snr"]) if d["snr"] else 0
            scr = np.median(d["scr"]) if d["scr"] else 0
            print(f"  {name}: in frame {d['in']}/{d['n']}, detectable {d['det']}/{d['n']}, "
                  f"median SNR {snr:.1f}, SCR {scr:.1f}")


if __name__ == "__main__":
    main()
