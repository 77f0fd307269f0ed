#!/usr/bin/env python3
"""Reads a dataset made by `irsim dataset` with the formats' own tools and checks every export against the
sequences' labels.jsonl:

- COCO: every file loads with pycocotools; evaluated against itself (boxes and masks), AP = 1; every box is the
  label's box; every segmentation decodes to the target's mask pixels.
- MOTChallenge: every gt.txt loads with py-motmetrics (`mot15-2D`), whose 0-based boxes are the labels' boxes.
- YOLO: data.yaml and the label files read by a minimal reader as a YOLO loader reads them (labels found by
  swapping /images/ for /labels/), boxes back in pixels equal to COCO's.
- SIRST: binary masks of the frames' size whose pixels are the union of the targets' masks.
- Split: every sequence in exactly one set, and each export's set the split's.

Usage: check_dataset.py DIR. Prints one line per check; exits 1 on the first failure.
"""

import contextlib
import io
import json
import sys
from pathlib import Path

import numpy as np
from PIL import Image


def fail(msg):
    print(f"FAIL: {msg}")
    sys.exit(1)


def close(a, b, tol=1.5e-3):
    return all(abs(x - y) <= tol for x, y in zip(a, b))


def main(root):
    root = Path(root)
    sets = ("train", "val", "test")
    split = {s: (root / "splits" / f"{s}.txt").read_text().split() for s in sets}
    seqs = sorted(p.name for p in (root / "sequences").iterdir() if p.is_dir() and not p.name.startswith("."))
    owner = {}
    for s, names in split.items():
        for n in names:
            if n in owner:
                fail(f"{n} is in both {owner[n]} and {s}")
            owner[n] = s
    if sorted(owner) != seqs:
        fail(f"the split lists {sorted(owner)}, the dataset has {seqs}")
    print(f"split: {len(seqs)} sequences, each in one set ({', '.join(f'{s} {len(split[s])}' for s in sets)})")

    # the labels, by (sequence, frame, track id)
    labels = {}
    for seq in seqs:
        for line in (root / "sequences" / seq / "labels.jsonl").read_text().splitlines():
            fl = json.loads(line)
            for t in fl["targets"]:
                if t["in_frame"]:
                    labels[(seq, fl["frame"], t["id"])] = t

    # COCO, with pycocotools
    from pycocotools import mask as mask_utils
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    with contextlib.redirect_stdout(io.StringIO()):
        coco = COCO(str(root / "coco" / "all.json"))
    anns = coco.loadAnns(coco.getAnnIds())
    if len(anns) != len(labels):
        fail(f"coco/all.json has {len(anns)} annotations, labels.jsonl {len(labels)} targets in frame")
    by_key = {}
    for a in anns:
        img = coco.imgs[a["image_id"]]
        key = (img["sequence"], img["frame"], a["track_id"])
        t = labels.get(key)
        if t is None:
            fail(f"annotation {a['id']} ({key}) has no label")
        x0, y0, x1, y1 = t["bbox_px"]
        if not close(a["bbox"], [x0, y0, x1 - x0, y1 - y0]):
            fail(f"annotation {a['id']}: bbox {a['bbox']}, label {t['bbox_px']}")
        mask = np.array(Image.open(root / img["file_name"].replace("/frames/", "/masks/")))
        own = mask == t["id"]
        decoded = coco.annToMask(a).astype(bool)
        if own.any() and not np.array_equal(decoded, own):
            fail(f"annotation {a['id']}: segmentation is not the target's mask pixels")
        if own.any() and a["area"] != own.sum():
            fail(f"annotation {a['id']}: area {a['area']}, mask {own.sum()} px")
        if a["attributes"]["snr"] != t["snr"]:
            fail(f"annotation {a['id']}: snr differs from the label")
        by_key[key] = (a, img)
    print(f"coco/all.json: {len(coco.imgs)} images, {len(anns)} annotations, boxes and masks equal the labels")
    for iou in ("bbox", "segm"):
        results = [
            {"image_id": a["image_id"], "category_id": a["category_id"], "bbox": a["bbox"],
             "segmentation": mask_utils.frPyObjects(a["segmentation"], *a["segmentation"]["size"]), "score": 1.0}
            for a in anns
        ]
        for r in results:
            r["segmentation"]["counts"] = r["segmentation"]["counts"].decode()
        with contextlib.redirect_stdout(io.StringIO()):
            dt = coco.loadRes(results)
            ev = COCOeval(coco, dt, iou)
            ev.params.areaRng = [[0, 1e10]] * 4
            ev.evaluate()
            ev.accumulate()
            ev.summarize()
        ap = ev.stats[0]
        if abs(ap - 1.0) > 1e-9:
            fail(f"COCO {iou} AP of the annotations against themselves is {ap}, not 1")
        print(f"coco/all.json against itself ({iou}): AP = {ap:.3f}")
    for s in sets:
        with contextlib.redirect_stdout(io.StringIO()):
            part = COCO(str(root / "coco" / f"{s}.json"))
        if any(img["split"] != s or img["sequence"] not in split[s] for img in part.imgs.values()):
            fail(f"coco/{s}.json holds an image of another set")
        if len(part.imgs) != sum(1 for img in coco.imgs.values() if img["sequence"] in split[s]):
            fail(f"coco/{s}.json misses images of its set")
    print("coco/{train,val,test}.json: load, hold their set's images only")

    # MOTChallenge, with py-motmetrics
    import motmetrics as mm

    n = 0
    for s in sets:
        for seq in split[s]:
            d = root / "mot" / s / seq
            gt = mm.io.loadtxt(str(d / "gt" / "gt.txt"), fmt="mot15-2D")
            info = (d / "seqinfo.ini").read_text()
            frames = len(list((d / "img1").iterdir()))
            if f"seqLength={frames}" not in info:
                fail(f"{d}: seqinfo.ini says otherwise than img1/'s {frames} frames")
            for (frame, tid), row in gt.iterrows():
                t = labels.get((seq, frame - 1, tid))
                if t is None:
                    fail(f"{d}/gt/gt.txt: frame {frame} id {tid} has no label")
                x0, y0, x1, y1 = t["bbox_px"]
                if not close([row.X, row.Y, row.Width, row.Height], [x0, y0, x1 - x0, y1 - y0]):
                    fail(f"{d}/gt/gt.txt: frame {frame} id {tid}: {list(row)[:4]} against the label {t['bbox_px']}")
                n += 1
    if n != len(labels):
        fail(f"the MOT files hold {n} boxes, the labels {len(labels)}")
    print(f"mot/: {n} boxes loaded by py-motmetrics equal the labels (0-based after its 1-based reading)")

    # YOLO, as a loader reads it
    yaml = (root / "yolo" / "data.yaml").read_text().splitlines()
    names = {}
    dirs = {}
    for line in yaml:
        if line.startswith("#") or not line.strip():
            continue
        if line.startswith("  ") and ":" in line:
            i, name = line.strip().split(":", 1)
            names[int(i)] = name.strip()
        elif ":" in line:
            k, v = line.split(":", 1)
            dirs[k.strip()] = v.strip()
    nc = int(dirs["nc"])
    if sorted(names) != list(range(nc)):
        fail(f"data.yaml: names {names} for nc {nc}")
    categories = {c["id"]: c["name"] for c in coco.loadCats(coco.getCatIds())}
    m = 0
    for s in sets:
        images = sorted((root / "yolo" / dirs[s]).glob("*.png"))
        for im in images:
            lab = Path(str(im).replace("/images/", "/labels/")).with_suffix(".txt")
            w, h = Image.open(im).size
            seq, frame = im.stem.rsplit("_", 1)
            if seq not in split[s]:
                fail(f"{im} is in {s}, its sequence is not")
            for line in lab.read_text().splitlines():
                c, xc, yc, bw, bh = line.split()
                c = int(c)
                xc, yc, bw, bh = (float(v) for v in (xc, yc, bw, bh))
                if not (0 <= c < nc and all(0 <= v <= 1 for v in (xc, yc, bw, bh))):
                    fail(f"{lab}: `{line}` out of range")
                box = [(xc - bw / 2) * w, (yc - bh / 2) * h, bw * w, bh * h]
                hits = [a for (sq, fr, _), (a, _) in by_key.items() if sq == seq and fr == int(frame)
                        and categories[a["category_id"]] == names[c] and close(a["bbox"], box, 2e-3 * max(w, h))]
                if not hits:
                    fail(f"{lab}: `{line}` matches no COCO box of its class")
                m += 1
    if m != len(labels):
        fail(f"the YOLO files hold {m} boxes, the labels {len(labels)}")
    print(f"yolo/: {m} boxes in {nc} classes equal COCO's")

    # SIRST masks
    k = 0
    for s in sets:
        for stem in (root / "sirst" / f"{s}.txt").read_text().split():
            img = Image.open(root / "sirst" / "images" / f"{stem}.png")
            mk = np.array(Image.open(root / "sirst" / "masks" / f"{stem}.png"))
            seq, frame = stem.rsplit("_", 1)
            ids = np.array(Image.open(root / "sequences" / seq / "masks" / f"{frame}.png"))
            if mk.shape != (img.size[1], img.size[0]) or set(np.unique(mk)) - {0, 255}:
                fail(f"sirst/masks/{stem}.png is not a binary mask of its image's size")
            if not np.array_equal(mk > 0, ids > 0):
                fail(f"sirst/masks/{stem}.png differs from the targets' masks")
            k += 1
    print(f"sirst/: {k} binary masks equal the targets' masks")
    print("all checks passed")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        print(__doc__)
        sys.exit(2)
    main(sys.argv[1])
