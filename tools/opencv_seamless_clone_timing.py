#!/usr/bin/env python3
"""Times OpenCV's seamlessClone (NORMAL_CLONE, one thread) on a square patch, for comparison with
`cargo bench --bench imaging` (fusion/direct_dst/<side>).

Usage: pip install opencv-python-headless numpy; python3 tools/opencv_seamless_clone_timing.py [side ...]
Prints one line per side: side, median milliseconds per call over 200 calls.
"""
import sys
import time

import cv2
import numpy as np


def main() -> None:
    cv2.setNumThreads(1)
    sides = [int(s) for s in sys.argv[1:]] or [16, 32, 64, 128]
    rng = np.random.default_rng(1)
    for side in sides:
        dst = (100 + 50 * rng.random((side + 64, side + 64, 3))).astype(np.uint8)
        y, x = np.mgrid[0:side, 0:side]
        c = side / 2
        blob = 120 * np.exp(-((x - c) / (side / 8)) ** 2 - ((y - c) / (side / 12)) ** 2)
        src = np.repeat(blob[:, :, None], 3, axis=2).astype(np.uint8)
        mask = np.full((side, side), 255, np.uint8)
        center = (dst.shape[1] // 2, dst.shape[0] // 2)
        times = []
        for _ in range(200):
            t0 = time.perf_counter()
            cv2.seamlessClone(src, dst, mask, center, cv2.NORMAL_CLONE)
            times.append(time.perf_counter() - t0)
        print(f"{side} {1e3 * float(np.median(times)):.3f} ms")


if __name__ == "__main__":
    main()
