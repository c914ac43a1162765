#!/usr/bin/env python3
"""How much of a difference between two runs is the run's own spread.

A run of the estimator is deterministic, but not smooth in its input: a
microsecond's change of the time shift moves a keyframe decision or a
feature track, and from there the whole run goes another way. Score the
same settings on copies of the sets that differ only negligibly
(`wrong_calibration.py SETS OUT --angle-deg 0 --move-mm 0 --shift-s
1e-6`, then 2e-6, ...) and give this script the `run_sets.py --out`
files, one per copy: it prints each run's ATE on every copy and its
spread (largest over smallest), and each set's mean on every copy.

With `--vs`, a second list of files, one per copy in the same order,
each ratio (a run's ATE over the other's, a set mean over the other's)
is printed per copy, so a claimed gain or loss can be held against its
own spread. The other side may be another field of the same files
(`--vs-field ate_relative_m`: the two stages against the relative stage
of the same run) or another mode (`--vs-mode stereo`: an inertial mode
against the same cameras without the IMU).

usage: bench/accuracy/spread.py A0.json A1.json ... [--field ate_m]
           [--vs B0.json B1.json ... | --vs-same] [--vs-field F] [--vs-mode M]
"""
import argparse, json, sys


def load(path):
    try:
        with open(path) as f:
            rows = json.load(f)
    except (OSError, ValueError) as e:
        sys.exit(f"{path}: {e} (a run_sets.py --out file)")
    return {(r.get("set"), r["sequence"], r["mode"]): r for r in rows}


def value(rows, key, field):
    r = rows.get(key)
    return None if r is None or "error" in r else r.get(field)


def mean(v):
    return sum(v) / len(v) if v else None


def spread(v):
    v = [x for x in v if x]
    return f"{100 * (max(v) / min(v) - 1):.1f} %" if len(v) > 1 else "-"


def fmt(v, spec=".4f"):
    return "-" if v is None else format(v, spec)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="\n\n".join(__doc__.split("\n\n")[1:]),
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="+", help="run_sets.py --out files, one per copy")
    ap.add_argument("--field", default="ate_m", help="the value compared [ate_m]")
    other_side = ap.add_mutually_exclusive_group()
    other_side.add_argument("--vs", nargs="+", help="the other side's files, one per copy, same order")
    other_side.add_argument("--vs-same", action="store_true", help="the other side is in the same files")
    ap.add_argument("--vs-field", help="the other side's field [--field]")
    ap.add_argument("--vs-mode", help="the other side's mode [each row's own]")
    a = ap.parse_args()
    side_a = [load(p) for p in a.files]
    side_b = None
    if a.vs_same:
        side_b = side_a
    elif a.vs:
        if len(a.vs) != len(a.files):
            sys.exit(f"--vs has {len(a.vs)} files for {len(a.files)} copies: one per copy, same order")
        side_b = [load(p) for p in a.vs]
    vs_field = a.vs_field or a.field
    keys = [k for k in side_a[0] if all(k in rows for rows in side_a)]
    if a.vs_mode:
        keys = [k for k in keys if k[2] != a.vs_mode]
    other = lambda k: (k[0], k[1], a.vs_mode) if a.vs_mode else k

    n = len(side_a)
    head = "| set | sequence | mode | " + " | ".join(f"copy {i}" for i in range(n)) + " | spread |"
    if side_b:
        head += " ratio per copy | ratio spread |"
    print(head)
    print("|" + "---|" * (head.count("|") - 1))
    for k in keys:
        va = [value(rows, k, a.field) for rows in side_a]
        line = f"| {k[0]} | {k[1]} | {k[2]} | " + " | ".join(fmt(v) for v in va) + f" | {spread(va)} |"
        if side_b:
            ra = [x / y if x and y else None
                  for x, y in zip(va, (value(rows, other(k), vs_field) for rows in side_b))]
            line += " " + ", ".join(fmt(r, ".3f") for r in ra) + f" | {spread(ra)} |"
        print(line)

    print()
    groups = sorted({(k[0], k[2]) for k in keys}, key=lambda g: [x or "" for x in g])
    head = "| set | mode | runs | " + " | ".join(f"mean, copy {i}" for i in range(n)) + " | spread |"
    if side_b:
        head += " ratio of means per copy | ratio spread |"
    print(head)
    print("|" + "---|" * (head.count("|") - 1))
    for s, mode in groups:
        ks = [k for k in keys if k[0] == s and k[2] == mode]
        # A mean over the runs every copy (and every other side) has.
        ks = [k for k in ks if all(value(rows, k, a.field) for rows in side_a)
              and (not side_b or all(value(rows, other(k), vs_field) for rows in side_b))]
        if not ks:
            continue
        ma = [mean([value(rows, k, a.field) for k in ks]) for rows in side_a]
        line = f"| {s} | {mode} | {len(ks)} | " + " | ".join(fmt(v) for v in ma) + f" | {spread(ma)} |"
        if side_b:
            mb = [mean([value(rows, other(k), vs_field) for k in ks]) for rows in side_b]
            ra = [x / y for x, y in zip(ma, mb)]
            line += " " + ", ".join(fmt(r, ".3f") for r in ra) + f" | {spread(ra)} |"
        print(line)


if __name__ == "__main__":
    main()
