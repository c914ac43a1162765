#!/usr/bin/env python3
"""CHOLMOD peer for `rigslam map solve`.

Reads the same edges file (`# landmarks N edges M reference R`, then
`i j ex ey ez s00 s01 s02 s11 s12 s22`), assembles A L = B (paper eq. 54-57:
per edge A_ii += S, A_jj += S, A_ij = A_ji -= S, B_i -= S y, B_j += S y) with
vectorised numpy into a scipy CSC matrix with the reference landmark's rows
and columns left out, and solves with scikit-sparse's CHOLMOD (supernodal
analyze + factorize + solve). Timing keys match `rigslam map solve --json`;
reading the text is excluded on both sides.

Usage: cholmod_map_solve.py EDGES OUT [--json]
"""
import json
import sys
import time

import numpy as np
import scipy
import scipy.sparse as sp
from sksparse.cholmod import analyze


def main():
    edges_path, out_path = sys.argv[1], sys.argv[2]
    as_json = "--json" in sys.argv[3:]
    with open(edges_path) as f:
        header = f.readline().split()
    fields = dict(zip(header[1::2], header[2::2]))
    n, m, ref = int(fields["landmarks"]), int(fields["edges"]), int(fields["reference"])
    t = time.perf_counter()
    data = np.loadtxt(edges_path, comments="#", ndmin=2)
    read_ms = (time.perf_counter() - t) * 1e3
    assert data.shape == (m, 11), data.shape

    t0 = time.perf_counter()
    ids = data[:, :2].astype(np.int64)
    # Unknown index of each end: the reference has none (-1), later ids shift down.
    u = np.where(ids < ref, ids, ids - 1)
    u[ids == ref] = -1
    ui, uj = u[:, 0], u[:, 1]
    y = data[:, 2:5]
    s00, s01, s02, s11, s12, s22 = (data[:, k] for k in range(5, 11))
    S = np.stack([np.stack([s00, s01, s02], 1), np.stack([s01, s11, s12], 1), np.stack([s02, s12, s22], 1)], 1)
    Sy = np.einsum("krc,kc->kr", S, y)
    r3 = np.arange(3)
    rows, cols, vals = [], [], []
    for a, b, sign in ((ui, ui, 1.0), (uj, uj, 1.0), (ui, uj, -1.0), (uj, ui, -1.0)):
        keep = (a >= 0) & (b >= 0)
        a, b, Sk = a[keep], b[keep], S[keep]
        rows.append(np.broadcast_to(3 * a[:, None, None] + r3[None, :, None], Sk.shape).ravel())
        cols.append(np.broadcast_to(3 * b[:, None, None] + r3[None, None, :], Sk.shape).ravel())
        vals.append((sign * Sk).ravel())
    dim = 3 * (n - 1)
    A = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(dim, dim)).tocsc()
    B = np.zeros(dim)
    for a, sign in ((ui, -1.0), (uj, 1.0)):
        keep = a >= 0
        np.add.at(B, (3 * a[keep][:, None] + r3).ravel(), sign * Sy[keep].ravel())
    assemble_ms = (time.perf_counter() - t0) * 1e3

    t = time.perf_counter()
    factor = analyze(A, mode="supernodal")
    factor.cholesky_inplace(A)
    factor_ms = (time.perf_counter() - t) * 1e3
    t = time.perf_counter()
    x = factor(B)
    solve_ms = (time.perf_counter() - t) * 1e3
    total_ms = (time.perf_counter() - t0) * 1e3

    L = np.insert(x.reshape(n - 1, 3), ref, 0.0, axis=0)
    with open(out_path, "w") as f:
        for k in range(n):
            f.write(f"{k} {float(L[k, 0])!r} {float(L[k, 1])!r} {float(L[k, 2])!r}\n")
    report = {
        "landmarks": n,
        "edges": m,
        "assemble_ms": assemble_ms,
        "factor_ms": factor_ms,
        "solve_ms": solve_ms,
        "total_ms": total_ms,
        "read_ms": read_ms,
        "factor_nnz": int(factor.L().nnz),
        "peer": f"cholmod (scikit-sparse 0.4.16, scipy {scipy.__version__})",
    }
    print(json.dumps(report) if as_json else report)


if __name__ == "__main__":
    main()
