#!/usr/bin/env python3
"""OpenCV's seamlessClone (NORMAL_CLONE, one thread) on the patches `irsim bench report` fuses, timed, for the
report's side-by-side comparison. The report runs this script itself (it is built into the program) wherever
`python3 -c "import cv2, numpy"` works; it can also be run by hand on a directory the report left with
`IRSIM_KEEP_OPENCV_CASES=1`.

Usage: pip install opencv-python-headless numpy; python3 tools/opencv_seamless_clone.py DIR

DIR holds cases.json, a list of {"name", "width", "height", "x0", "y0", "side", "calls"}, and per case
NAME.bg (the background, height x width bytes) and NAME.src (the patch, side x side bytes), 8-bit gray, row-major.
Writes NAME.out (the cloned frame, height x width bytes) and opencv.json: the OpenCV version and, per case, the
median seconds per call over `calls` calls.

seamlessClone clears the outer ring of the mask it is given and centres the mask's bounding box on the point,
so each patch goes in with a one-pixel margin and the centre x0 + side // 2, y0 + side // 2: the patch then
covers exactly the region [x0, x0 + side) x [y0, y0 + side) of the frame.
"""
import json
import os
import sys
import time

import cv2
import numpy as np


def main() -> None:
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    folder = sys.argv[1]
    cv2.setNumThreads(1)
    with open(os.path.join(folder, "cases.json"), encoding="utf-8") as f:
        cases = json.load(f)
    seconds = {}
    for case in cases:
        name, w, h, side = case["name"], case["width"], case["height"], case["side"]
        bg = np.fromfile(os.path.join(folder, name + ".bg"), np.uint8).reshape(h, w)
        patch = np.fromfile(os.path.join(folder, name + ".src"), np.uint8).reshape(side, side)
        dst = np.ascontiguousarray(np.repeat(bg[:, :, None], 3, axis=2))
        src = np.zeros((side + 2, side + 2, 3), np.uint8)
        src[1:-1, 1:-1] = patch[:, :, None]
        mask = np.full((side + 2, side + 2), 255, np.uint8)
        centre = (case["x0"] + side // 2, case["y0"] + side // 2)
        out = cv2.seamlessClone(src, dst, mask, centre, cv2.NORMAL_CLONE)
        times = []
        for _ in range(case["calls"]):
            t0 = time.perf_counter()
            cv2.seamlessClone(src, dst, mask, centre, cv2.NORMAL_CLONE)
            times.append(time.perf_counter() - t0)
        np.ascontiguousarray(out[:, :, 0]).tofile(os.path.join(folder, name + ".out"))
        seconds[name] = float(np.median(times))
    with open(os.path.join(folder, "opencv.json"), "w", encoding="utf-8") as f:
        json.dump({"version": cv2.__version__, "seconds": seconds}, f)


if __name__ == "__main__":
    main()
