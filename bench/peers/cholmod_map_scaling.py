#!/usr/bin/env python3
"""Driver of cholmod_map_scaling.sh: runs `rigslam map solve --json` and the
CHOLMOD peer on the same edges files under /usr/bin/time -v, alternating,
and prints markdown rows (best of the repeats per side)."""
import json
import os
import re
import subprocess
import sys

import numpy as np

BIN, WORK, SIZES = sys.argv[1], sys.argv[2], [int(s) for s in sys.argv[3:]]
PEER = [sys.executable, "bench/peers/cholmod_map_solve.py"]


def timed(cmd):
    out = subprocess.run(["/usr/bin/time", "-v", *cmd], capture_output=True, text=True, check=True)
    rss_kb = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", out.stderr).group(1))
    report = json.loads(out.stdout.strip().splitlines()[-1])
    report["peak_rss_mb"] = rss_kb / 1024
    return report


print("| landmarks | edges | rigslam assemble / factor / solve ms | rigslam total ms | rigslam peak RSS MB | "
      "CHOLMOD assemble / factor / solve ms | CHOLMOD total ms | CHOLMOD peak RSS MB | total ratio | factor ratio | max position difference m |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
for n in SIZES:
    edges = os.path.join(WORK, f"{n}.edges")
    if not os.path.exists(edges):
        subprocess.run([BIN, "map", "generate", "--landmarks", str(n), "--out", edges,
                        "--truth", os.path.join(WORK, f"{n}.truth")], check=True, capture_output=True)
    repeats = 1 if n >= 1_000_000 else 3
    ours, peer = [], []
    for _ in range(repeats):
        ours.append(timed([BIN, "map", "solve", "--edges", edges, "--out", os.path.join(WORK, f"{n}.rigslam"), "--json"]))
        peer.append(timed([*PEER, edges, os.path.join(WORK, f"{n}.cholmod"), "--json"]))
    a = min(ours, key=lambda r: r["total_ms"])
    b = min(peer, key=lambda r: r["total_ms"])
    xa = np.loadtxt(os.path.join(WORK, f"{n}.rigslam"))[:, 1:]
    xb = np.loadtxt(os.path.join(WORK, f"{n}.cholmod"))[:, 1:]
    diff = float(np.abs(xa - xb).max())
    print(f"| {n} | {a['edges']} | {a['assemble_ms']:.0f} / {a['factor_ms']:.0f} / {a['solve_ms']:.0f} | {a['total_ms']:.0f} | "
          f"{max(r['peak_rss_mb'] for r in ours):.0f} | {b['assemble_ms']:.0f} / {b['factor_ms']:.0f} / {b['solve_ms']:.0f} | "
          f"{b['total_ms']:.0f} | {max(r['peak_rss_mb'] for r in peer):.0f} | {b['total_ms'] / a['total_ms']:.2f} | "
          f"{b['factor_ms'] / a['factor_ms']:.2f} | {diff:.1e} |", flush=True)
