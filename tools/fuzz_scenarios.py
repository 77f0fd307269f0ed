#!/usr/bin/env python3
"""Mutation fuzzing of scenario files against the release binary.

Every numeric, string, array and table in the shipped scenarios is mutated in turn (extreme numbers, NaN,
infinities, wrong types, arrays one element too long or too short, deleted keys, unknown keys); each mutant is
recorded for a few frames as float `.npy` frames and checked:

- the exit status is 0 (accepted) or 2 (refused), never a panic (101), another status or a hang;
- a refusal names `file:line:column`, and the field it names is the mutated one (or lies inside it);
- an accepted run has `status: complete` in its manifest, a finite number in every frame pixel and every
  label field (no `null`), and every box inside the image.

Usage: python3 tools/fuzz_scenarios.py [--bin PATH] [--frames N] [--jobs N] [--only SUBSTRING] [--json] [SCENARIO ...]
Needs numpy and tomli-w (`pip install numpy tomli-w`). Prints one line per failure and a summary; exit 1 if any.
"""

import argparse
import concurrent.futures
import copy
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import itertools
import tomllib

import numpy as np
import tomli_w

NUMBERS = [0, -1, 1e308, -1e308, 1e-320, -1e-320, float("nan"), float("inf"), float("-inf"), 1e39, 2.0**63]
WRONG_TYPES = ["x", True, [], {}]
COUNTER = itertools.count()


def leaves(node, path=""):
    """(path, value) of every value in the tree, tables and arrays included."""
    if isinstance(node, dict):
        for k, v in node.items():
            p = f"{path}.{k}" if path else k
            yield p, v
            yield from leaves(v, p)
    elif isinstance(node, list):
        for i, v in enumerate(node):
            p = f"{path}[{i}]"
            if isinstance(v, (dict, list)):
                yield p, v
                yield from leaves(v, p)
            else:
                yield p, v


def split(path):
    parts = []
    for part in path.split("."):
        m = re.match(r"^([^\[]+)((?:\[\d+\])*)$", part)
        parts.append(m.group(1))
        parts.extend(int(i) for i in re.findall(r"\[(\d+)\]", m.group(2)))
    return parts


def set_at(tree, path, value, delete=False):
    parts = split(path)
    node = tree
    for p in parts[:-1]:
        node = node[p]
    if delete:
        del node[parts[-1]]
    else:
        node[parts[-1]] = value


def mutants(tree):
    for path, value in list(leaves(tree)):
        if path in ("name", "description") or path.endswith(".name") and "targets" not in path:
            continue
        if isinstance(value, bool):
            candidates = ["x", 3]
        elif isinstance(value, (int, float)):
            candidates = NUMBERS + WRONG_TYPES
        elif isinstance(value, str):
            candidates = [1.5, "no_such_value", ""]
        elif isinstance(value, list):
            candidates = [[], value + value[-1:] if value else [0], value[:-1]]
        else:
            candidates = [5, {**value, "no_such_key": 1}]
        for c in candidates:
            yield path, "set", c
        if isinstance(value, dict) or "[" not in path.rsplit(".", 1)[-1]:
            yield path, "delete", None


def check_run(args, base_text_dir, name, tree, path, how, value):
    m = copy.deepcopy(tree)
    try:
        set_at(m, path, value, delete=how == "delete")
        text = json.dumps(m, indent=1) if args.json else tomli_w.dumps(m)
    except Exception:
        return None
    with tempfile.TemporaryDirectory(dir=args.tmp) as d:
        scen = os.path.join(base_text_dir, f".fuzz_{os.getpid()}_{next(COUNTER)}.{'json' if args.json else 'toml'}")
        with open(scen, "w") as f:
            f.write(text)
        out = os.path.join(d, "out")
        what = f"{name}: {path} {how} {value!r}"
        try:
            p = subprocess.run(
                [args.bin, "record", scen, "--out", out, "--frames", str(args.frames), "--format", "npy", "--quiet"],
                capture_output=True,
                text=True,
                timeout=args.timeout,
            )
        except subprocess.TimeoutExpired:
            return f"HANG {what}"
        finally:
            os.remove(scen)
        err = p.stderr.strip().replace("\n", " | ")
        if p.returncode == 2:
            if not re.search(r"\.(toml|json|csv):\d+:\d+: field `", p.stderr):
                return f"UNLOCATED {what}: {err[:300]}"
            field = re.search(r"field `([^`]*)`", p.stderr).group(1)
            if "no target named" in p.stderr:
                return None
            if how == "set" and not (field == path or field.startswith(path + ".") or field.startswith(path + "[")
                                     or path.startswith(field + "[") and isinstance(value, (int, float))):
                return f"WRONG-FIELD {what}: named `{field}`: {err[:300]}"
            return None
        if p.returncode != 0:
            return f"EXIT {p.returncode} {what}: {err[:400]}"
        return check_output(out, what)


def check_output(out, what):
    try:
        manifest = json.load(open(os.path.join(out, "manifest.json")))
    except Exception as e:
        return f"MANIFEST {what}: {e}"
    if manifest.get("status") != "complete":
        return f"MANIFEST {what}: status {manifest.get('status')}"

    def bad_const(c):
        raise ValueError(f"non-finite {c}")

    w = h = None
    frames = sorted(os.listdir(os.path.join(out, "frames")))
    for fname in frames:
        a = np.load(os.path.join(out, "frames", fname))
        h, w = a.shape
        if not np.isfinite(a).all():
            return f"NONFINITE-FRAME {what}: {fname} has {(~np.isfinite(a)).sum()} non-finite pixels"
    n = 0
    for line in open(os.path.join(out, "labels.jsonl")):
        n += 1
        try:
            lab = json.loads(line, parse_constant=bad_const)
        except ValueError as e:
            return f"LABEL {what}: {e}"
        bad = []

        def walk(x, p):
            if x is None:
                bad.append(p)
            elif isinstance(x, float) and not math.isfinite(x):
                bad.append(p)
            elif isinstance(x, dict):
                for k, v in x.items():
                    walk(v, f"{p}.{k}")
            elif isinstance(x, list):
                for i, v in enumerate(x):
                    walk(v, f"{p}[{i}]")

        walk(lab, "")
        if bad:
            return f"NULL-LABEL {what}: frame {lab.get('frame')}: {bad[:4]}"
        for t in lab.get("targets", []):
            x0, y0, x1, y1 = t["bbox_px"]
            if w is not None and not (0 <= x0 <= x1 <= w and 0 <= y0 <= y1 <= h):
                return f"BOX {what}: {t['name']} {t['bbox_px']} outside {w}x{h}"
    if n != len(frames):
        return f"COUNT {what}: {len(frames)} frames, {n} label lines"
    return None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scenarios", nargs="*")
    ap.add_argument("--bin", default=os.environ.get("IRSIM_BIN", "target/release/irsim"))
    ap.add_argument("--frames", type=int, default=2)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--timeout", type=float, default=120)
    ap.add_argument("--only", default="")
    ap.add_argument("--tmp", default=None)
    ap.add_argument("--json", action="store_true", help="write the mutants as JSON scenarios")
    args = ap.parse_args()
    scenarios = args.scenarios or sorted(
        os.path.join("scenarios", f) for f in os.listdir("scenarios") if f.endswith(".toml")
    )
    jobs = []
    for s in scenarios:
        tree = tomllib.load(open(s, "rb"))
        for path, how, value in mutants(tree):
            if args.only in path:
                jobs.append((os.path.dirname(os.path.abspath(s)), os.path.basename(s), tree, path, how, value))
    print(f"{len(jobs)} mutants", flush=True)
    failures = 0
    with concurrent.futures.ThreadPoolExecutor(args.jobs) as ex:
        for r in ex.map(lambda j: check_run(args, *j), jobs):
            if r:
                failures += 1
                print(r, flush=True)
    print(f"{failures} failures in {len(jobs)} mutants")
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
