#!/usr/bin/env python3
"""The second stage's frame-node map, solved offline from one run's landmarks.

`rigslam run --landmarks lm.csv --trajectory rel.csv` writes what the
relative stage hands the absolute stage (each tracked frame's landmarks
in its body frame, with covariances) and the relative trajectory. This
script builds the frame-node edge map from them the way the absolute
stage does in outline (one frame in `--every` a node joined to each
landmark it sees by the measured offset `R y`, odometry edges between
consecutive nodes with `--odometry-sigma` m per sqrt(m), the offsets'
own covariances; no recognition, so a landmark seen again after its track
ended is a new one), solves it as one sparse least-squares problem, and
scores the nodes against the ground truth (se3-aligned, at the node
stamps) next to the relative stage's own poses there. It runs in seconds,
so a change to the map can be tried before it is built.

Variants: `--walks` adds a rotation unknown per node (linearised at the
relative stage's attitude, a random walk of that many rad per sqrt(s)
between consecutive nodes, the first node's held; 0 = none, the
default); `--offset-cov-scale` multiplies the offsets' covariances;
`--true-attitude` turns the offsets by the ground truth's attitude (in
the relative stage's world) instead, to measure what the attitude costs.
The ground truth is only used to score, and for `--true-attitude`.

usage: offline_map.py --landmarks lm.csv --trajectory rel.csv \\
         --groundtruth mav0/state_groundtruth_estimate0/data.csv [--walks 0 1e-4 1e-3]
"""

import argparse
import sys
from collections import defaultdict

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spl


def load_euroc(path):
    """EuRoC csv (t[ns], p, q wxyz, ...): stamps, positions, quaternions."""
    a = np.genfromtxt(path, delimiter=",", comments="#")
    if a.ndim != 2 or a.shape[1] < 8:
        sys.exit(f"{path}: expected EuRoC csv rows t_ns,px,py,pz,qw,qx,qy,qz")
    return a[:, 0].astype(np.int64), a[:, 1:4], a[:, 4:8]


def rot(q):
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def skew(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def umeyama(a, b):
    """R, t with b ~ R a + t (least squares, no scale)."""
    ma, mb = a.mean(0), b.mean(0)
    u, _, vt = np.linalg.svd((a - ma).T @ (b - mb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1, 1, d]) @ u.T
    return r, mb - r @ ma


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--landmarks", required=True, help="rigslam run --landmarks CSV")
    ap.add_argument("--trajectory", required=True, help="the relative trajectory, EuRoC csv (rigslam run --trajectory rel.csv)")
    ap.add_argument("--groundtruth", required=True, help="EuRoC ground truth csv")
    ap.add_argument("--every", type=int, default=5, help="one frame in this many a node [5]")
    ap.add_argument("--odometry-sigma", type=float, default=0.02, help="odometry edges, m per sqrt(m); 0: none [0.02]")
    ap.add_argument("--walks", type=float, nargs="+", default=[0.0], help="rotation random walks to try, rad per sqrt(s); 0: no rotation unknowns [0]")
    ap.add_argument("--offset-cov-scale", type=float, default=1.0, help="multiply the offsets' covariances [1]")
    ap.add_argument("--true-attitude", action="store_true", help="turn the offsets by the ground truth's attitude")
    ap.add_argument("--show-turns", action="store_true", help="with --walks: print every 20th node's estimated turn beside the truth's attitude change since the first node (deg, aligned world)")
    args = ap.parse_args()

    gt_t, gt_p, gt_q = load_euroc(args.groundtruth)
    rt, rp, rq = load_euroc(args.trajectory)
    lm = np.genfromtxt(args.landmarks, delimiter=",", names=True)
    if lm.size == 0:
        sys.exit(f"{args.landmarks}: no landmarks")
    t_l = lm["t_ns"].astype(np.int64)
    ids = lm["id"].astype(np.int64)
    y = np.stack([lm["x"], lm["y"], lm["z"]], 1)
    cov = np.stack([lm[c] for c in ["c00", "c01", "c02", "c11", "c12", "c22"]], 1)

    rel_index = {t: i for i, t in enumerate(rt)}
    nodes = np.array([t for t in np.unique(t_l)[::args.every] if t in rel_index])
    if len(nodes) < 3:
        sys.exit("fewer than 3 frame nodes with a relative pose: are the landmarks and the trajectory from the same run?")
    rows_at = defaultdict(list)
    for k, t in enumerate(t_l):
        rows_at[t].append(k)
    lid = {}
    for t in nodes:
        for k in rows_at[t]:
            lid.setdefault(ids[k], len(lid))
    n_l, n_f = len(lid), len(nodes)

    def truth(t):
        i = min(np.searchsorted(gt_t, t), len(gt_t) - 1)
        return gt_p[i], rot(gt_q[i])

    truth_f = np.array([truth(t)[0] for t in nodes])
    rel_f = np.array([rp[rel_index[t]] for t in nodes])
    r_truth_to_rel, _ = umeyama(truth_f, rel_f)

    def ate(f):
        r, t = umeyama(f, truth_f)
        e = (r @ f.T).T + t - truth_f
        return np.sqrt((e ** 2).sum(1).mean())

    def rotvec(m):
        angle = np.arccos(np.clip((np.trace(m) - 1) / 2, -1, 1))
        if angle < 1e-12:
            return np.zeros(3)
        return angle / (2 * np.sin(angle)) * np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]])

    print(f"{n_f} frame nodes, {n_l} landmarks; the relative stage's poses at the nodes: ATE {ate(rel_f) * 1000:.1f} mm")
    print("| map | nodes' ATE, mm |")
    print("|---|---|")
    for walk in args.walks:
        turn = walk > 0
        n = 3 * n_l + 3 * n_f + (3 * n_f if turn else 0)
        ii, jj, vv, rhs = [], [], [], []
        row = 0

        def add(blocks, target, info):
            nonlocal row
            w = np.linalg.cholesky(info).T
            for c0, jac in blocks:
                a = w @ jac
                for r in range(3):
                    for c in range(3):
                        if a[r, c] != 0.0:
                            ii.append(row + r)
                            jj.append(c0 + c)
                            vv.append(a[r, c])
            rhs.extend(w @ target)
            row += 3

        for f, t in enumerate(nodes):
            r_f = r_truth_to_rel @ truth(t)[1] if args.true_attitude else rot(rq[rel_index[t]])
            for k in rows_at[t]:
                c = cov[k]
                s = np.array([[c[0], c[1], c[2]], [c[1], c[3], c[4]], [c[2], c[4], c[5]]])
                yw = r_f @ y[k]
                blocks = [(3 * lid[ids[k]], np.eye(3)), (3 * n_l + 3 * f, -np.eye(3))]
                if turn:
                    blocks.append((3 * n_l + 3 * n_f + 3 * f, skew(yw)))
                add(blocks, yw, np.linalg.inv(r_f @ s @ r_f.T * args.offset_cov_scale))
        if args.odometry_sigma > 0:
            for f in range(1, n_f):
                d = rel_f[f] - rel_f[f - 1]
                var = args.odometry_sigma ** 2 * max(np.linalg.norm(d), 0.01)
                add([(3 * n_l + 3 * f, np.eye(3)), (3 * n_l + 3 * (f - 1), -np.eye(3))], d, np.eye(3) / var)
        add([(3 * n_l, np.eye(3))], rel_f[0], np.eye(3) * 1e12)
        if turn:
            o = 3 * n_l + 3 * n_f
            add([(o, np.eye(3))], np.zeros(3), np.eye(3) * 1e12)
            for f in range(1, n_f):
                dt = (nodes[f] - nodes[f - 1]) * 1e-9
                add([(o + 3 * f, np.eye(3)), (o + 3 * (f - 1), -np.eye(3))], np.zeros(3), np.eye(3) / (walk ** 2 * dt))
        a = sp.csr_matrix((vv, (ii, jj)), shape=(row, n))
        x = spl.spsolve((a.T @ a).tocsc(), a.T @ np.array(rhs))
        f_est = x[3 * n_l:3 * n_l + 3 * n_f].reshape(-1, 3)
        what = f"rotation unknowns, walk {walk:g} rad/sqrt(s)" if turn else "as built"
        if args.true_attitude:
            what += ", true attitudes"
        if args.offset_cov_scale != 1.0:
            what += f", offsets' covariance x{args.offset_cov_scale:g}"
        print(f"| {what} | {ate(f_est) * 1000:.1f} |")
        if turn and args.show_turns:
            r_align, _ = umeyama(f_est, truth_f)
            turns = x[3 * n_l + 3 * n_f:].reshape(-1, 3)
            first = None
            for f in range(0, n_f, 20):
                t = nodes[f]
                # The truth's attitude against the relative stage's, in the
                # aligned world, and its change since the first node.
                err = rotvec(truth(t)[1] @ (r_align @ rot(rq[rel_index[t]])).T)
                first = err if first is None else first
                est = np.degrees(r_align @ turns[f])
                print(f"    node {f:4d}: estimated turn {np.round(est, 2)} deg, the truth's change {np.round(np.degrees(err - first), 2)} deg")


if __name__ == "__main__":
    main()
