#!/usr/bin/env python3
"""The pipeline of `irsim bench`'s built-in cases as a researcher would write it with numpy and OpenCV, timed:
a yardstick from outside for irsim's frames per second (`irsim bench` runs the same two cases).

Per frame, as irsim does it:
1. a vibrating camera: a small random rotation about the line of sight, and the sky image's plane mapped onto
   the sensor by a homography (`cv2.warpPerspective`, bilinear, float32), the sky a 1024 × 1024 float32 image;
2. the optics: a separable Gaussian blur of about the PSF's width (`cv2.sepFilter2D`, 9 taps);
3. each target: a Gaussian ellipse of its projected size on a 17 × 17 patch, fused into the frame by
   `cv2.seamlessClone` (NORMAL_CLONE, 8-bit, three channels as OpenCV requires), the result's change added back
   to the float frame;
4. the readout: electrons from radiance, shot and read noise as one normal deviate per pixel
   (`numpy.random.Generator.standard_normal`, float32), gain, offset, clamp and round to 14-bit levels.

It simplifies in the peer's favour: no radiometry per target (a fixed peak), no labels, no atmosphere, a
Gaussian PSF instead of the band's Airy pattern, no non-uniformity maps.

Usage: python3 tools/numpy_peer.py [--frames N] [--size 256x256|640x512] [--targets K] [--threads T]
Prints frames per second (median of 3 runs). `--threads` sets OpenCV's threads (numpy's generator is
single-threaded).
"""
import argparse
import statistics
import time

import cv2
import numpy as np


def homography(w: int, h: int, angle_rad: float, dx: float, dy: float, scale: float) -> np.ndarray:
    """The sky image's plane to the sensor: a scale (sky texels per pixel), a rotation about the frame's centre
    and a shift in pixels, with a slight perspective tilt as a plane seen at a grazing angle has."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    to_centre = np.array([[1.0, 0.0, -w / 2], [0.0, 1.0, -h / 2], [0.0, 0.0, 1.0]])
    back = np.array([[1.0, 0.0, w / 2 + dx], [0.0, 1.0, h / 2 + dy], [0.0, 0.0, 1.0]])
    tilt = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 2e-4, 1.0]])
    zoom = np.diag([1.0 / scale, 1.0 / scale, 1.0])
    return back @ rot @ to_centre @ tilt @ zoom


def run(frames: int, w: int, h: int, targets: int, rng: np.random.Generator) -> float:
    sky = (2000.0 + 400.0 * rng.random((1024, 1024))).astype(np.float32)
    sky = cv2.GaussianBlur(sky, (0, 0), 6.0)
    kernel = cv2.getGaussianKernel(9, 1.2).astype(np.float32)
    yy, xx = np.mgrid[-8:9, -8:9].astype(np.float32)
    electrons_per_radiance, read_sigma_e, dn_per_e, offset_dn, top = 20.0, 30.0, 0.25, 1000.0, 16383.0
    start = time.perf_counter()
    for k in range(frames):
        # 1. vibrating camera, sky plane to sensor
        H = homography(w, h, 0.002 * np.sin(0.7 * k), 3.0 * np.sin(0.3 * k), 2.0 * np.cos(0.4 * k), 1.6)
        frame = cv2.warpPerspective(sky, H, (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                    borderMode=cv2.BORDER_REPLICATE)
        # 2. optics
        frame = cv2.sepFilter2D(frame, -1, kernel, kernel)
        # 3. targets, Poisson-fused
        for t in range(targets):
            x0 = int((37 * t + 5 * k) % (w - 40)) + 10
            y0 = int((53 * t + 3 * k) % (h - 40)) + 10
            a, b, th = 3.0 + t % 3, 1.5, 0.3 * t
            u = (xx * np.cos(th) + yy * np.sin(th)) / a
            v = (-xx * np.sin(th) + yy * np.cos(th)) / b
            blob = 600.0 * np.exp(-0.5 * (u * u + v * v))
            region = frame[y0:y0 + 17, x0:x0 + 17]
            lo, hi = float(region.min()), float(region.max() + blob.max())
            scale = 255.0 / max(hi - lo, 1e-6)
            bg8 = np.clip((frame - lo) * scale, 0, 255).astype(np.uint8)
            src8 = np.clip((region + blob - lo) * scale, 0, 255).astype(np.uint8)
            mask = np.full((19, 19), 255, np.uint8)
            src3 = cv2.cvtColor(cv2.copyMakeBorder(src8, 1, 1, 1, 1, cv2.BORDER_REPLICATE), cv2.COLOR_GRAY2BGR)
            bg3 = cv2.cvtColor(bg8, cv2.COLOR_GRAY2BGR)
            out = cv2.seamlessClone(src3, bg3, mask, (x0 + 8, y0 + 8), cv2.NORMAL_CLONE)[..., 0]
            change = (out[y0:y0 + 17, x0:x0 + 17].astype(np.float32) - bg8[y0:y0 + 17, x0:x0 + 17]) / scale
            region += change
        # 4. readout
        e = frame * electrons_per_radiance
        sigma = np.sqrt(np.maximum(e, 0.0) + read_sigma_e ** 2)
        e += sigma * rng.standard_normal((h, w), dtype=np.float32)
        np.clip(np.rint(offset_dn + e * dn_per_e), 0.0, top).astype(np.uint16)
    return frames / (time.perf_counter() - start)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--frames", type=int, default=300)
    p.add_argument("--size", default="256x256")
    p.add_argument("--targets", type=int, default=1)
    p.add_argument("--threads", type=int, default=2)
    a = p.parse_args()
    w, h = (int(x) for x in a.size.split("x"))
    cv2.setNumThreads(a.threads)
    rng = np.random.default_rng(1)
    run(10, w, h, a.targets, rng)
    fps = statistics.median(run(a.frames, w, h, a.targets, rng) for _ in range(3))
    print(f"numpy + OpenCV {cv2.__version__} peer, {w}x{h}, {a.targets} target(s), {a.threads} OpenCV threads: "
          f"{fps:.1f} frames/s")


if __name__ == "__main__":
    main()
