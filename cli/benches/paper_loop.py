#!/usr/bin/env python3
"""The paper's correction loop, literally, as its authors' stack would run it (NumPy + SciPy).

The speed bench (`cargo bench -p lanealign-cli --bench speed`) runs this next to `lanealign
correct` on the same input: it is the yardstick of the speed-up, not part of the product.
SPEC sections 2-3 exactly: every step re-matches the whole window (N nearest lane points from a
KD-tree, direction test, normal shooting), then trimmed ICP on the fixed pairs.

usage: paper_loop.py LANES_CSV POSES_KITTI PRESET OUT [--vectorized]
  LANES_CSV    lane_id,x,y in the planar odometry frame (../shared/data/reference/lanes)
  POSES_KITTI  KITTI camera poses (12 floats a line)
  OUT          corrected planar positions, one "x y" a line
  --vectorized match every window pose and candidate at once in arrays instead of the loop over
               poses and candidates the SPEC describes (same matches, faster)
Prints the whole process time and the loop's time per pose (microseconds) on stdout as
`total_us=... loop_us_per_pose=...`.
"""
import sys
import time

START = time.perf_counter()

import numpy as np  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

PRESETS = {  # M_min, M_max, N, E_max, epsilon
    "liodom": (50, 3000, 100, 50, 2.0),
    "basalt": (150, 3000, 10, 10, 1.0),
    "kiss-icp": (150, 1000, 100, 1000, 1.5),
    "orb-slam3": (150, 1000, 50, 100, 1.5),
}
RHO, ETA, L_MIN, TAU = 0.1, 0.5, 10.0, 0.95


def read_lanes(path):
    rows = np.loadtxt(path, delimiter=",", skiprows=1)
    ids, pts = rows[:, 0], rows[:, 1:3]
    seg_a = np.empty_like(pts)
    seg_b = np.empty_like(pts)
    valid = np.zeros(len(pts), dtype=bool)
    for lane in np.unique(ids):
        idx = np.flatnonzero(ids == lane)
        if len(idx) < 2:
            continue
        seg_a[idx[:-1]], seg_b[idx[:-1]] = pts[idx[:-1]], pts[idx[1:]]
        seg_a[idx[-1]], seg_b[idx[-1]] = pts[idx[-2]], pts[idx[-1]]
        valid[idx] = True
    d = seg_b - seg_a
    norm = np.linalg.norm(d, axis=1)
    valid &= norm > 0
    dirs = np.where(valid[:, None], d / np.where(norm > 0, norm, 1)[:, None], 0)
    return pts, seg_a, seg_b, dirs, valid


def trajectory_directions(window):
    """Unit forward differences (backward for the last pose), and which poses moved."""
    d_traj = np.empty_like(window)
    d_traj[:-1] = window[1:] - window[:-1]
    d_traj[-1] = window[-1] - window[-2]
    length = np.linalg.norm(d_traj, axis=1)
    moving = length > 0
    d_traj[moving] /= length[moving, None]
    return d_traj, moving


def nearest_by_index(tree, window, k):
    """The k nearest lane points of every window pose, equal distances ordered by point index."""
    dist, nearest = tree.query(window, k=k)
    dist, nearest = dist.reshape(len(window), k), nearest.reshape(len(window), k)
    order = np.lexsort((nearest, dist))
    return np.take_along_axis(nearest, order, axis=1)


def lane_match(window, tree, lanes, n):
    pts, seg_a, seg_b, dirs, valid = lanes
    k = min(n, len(pts))
    d_traj, moving = trajectory_directions(window)
    nearest = nearest_by_index(tree, window, k)
    sources, targets = [], []
    for i in np.flatnonzero(moving):
        x, d = window[i], d_traj[i]
        normal = np.array([-d[1], d[0]])
        for j in nearest[i]:
            if not valid[j] or d @ dirs[j] < TAU:
                continue
            a, b = seg_a[j], seg_b[j]
            ab = b - a
            den = ab[0] * normal[1] - ab[1] * normal[0]
            if den == 0:
                continue
            xa = x - a
            t = (xa[0] * normal[1] - xa[1] * normal[0]) / den
            if 0 <= t <= 1:
                sources.append(x)
                targets.append(a + t * ab)
                break
    return np.array(sources).reshape(-1, 2), np.array(targets).reshape(-1, 2)


def lane_match_vectorized(window, tree, lanes, n):
    """The same matches, every window pose and candidate tested at once in arrays."""
    pts, seg_a, seg_b, dirs, valid = lanes
    k = min(n, len(pts))
    d_traj, moving = trajectory_directions(window)
    nearest = nearest_by_index(tree, window, k)
    a, ab = seg_a[nearest], seg_b[nearest] - seg_a[nearest]
    normal = np.stack([-d_traj[:, 1], d_traj[:, 0]], axis=1)[:, None, :]
    den = ab[..., 0] * normal[..., 1] - ab[..., 1] * normal[..., 0]
    xa = window[:, None, :] - a
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (xa[..., 0] * normal[..., 1] - xa[..., 1] * normal[..., 0]) / den
    ok = (
        valid[nearest]
        & ((dirs[nearest] * d_traj[:, None, :]).sum(axis=2) >= TAU)
        & (den != 0)
        & (t >= 0)
        & (t <= 1)
        & moving[:, None]
    )
    rows = np.flatnonzero(ok.any(axis=1))
    first = ok[rows].argmax(axis=1)
    targets = a[rows, first] + t[rows, first, None] * ab[rows, first]
    return window[rows], targets


def kabsch(s, q):
    cs, cq = s.mean(axis=0), q.mean(axis=0)
    h = (s - cs).T @ (q - cq)
    u, _, vt = np.linalg.svd(h)
    r = vt.T @ u.T
    if np.linalg.det(r) < 0:
        vt[1] *= -1
        r = vt.T @ u.T
    return r, cq - r @ cs


def trimmed_icp(s, q):
    k = max(2, int(np.floor((1 - RHO) * len(s))))
    rot, trans = np.eye(2), np.zeros(2)
    prev, e = np.inf, np.inf
    cur = s.copy()
    for _ in range(50):
        res = np.linalg.norm(cur - q, axis=1)
        keep = np.argsort(res, kind="stable")[:k]
        r, t = kabsch(cur[keep], q[keep])
        cur = cur @ r.T + t
        rot, trans = r @ rot, r @ trans + t
        e = np.linalg.norm(cur[keep] - q[keep], axis=1).mean()
        if abs(prev - e) < 1e-8:
            break
        prev = e
    return rot, trans, e


def main():
    lanes_path, poses_path, preset, out_path = sys.argv[1:5]
    matcher = lane_match_vectorized if "--vectorized" in sys.argv[5:] else lane_match
    m_min, m_max, n, e_max, epsilon = PRESETS[preset]
    lanes = read_lanes(lanes_path)
    tree = cKDTree(lanes[0])
    cam = np.loadtxt(poses_path).reshape(-1, 3, 4)
    positions = np.stack([cam[:, 2, 3], -cam[:, 0, 3]], axis=1)
    rot_acc, trans_acc = np.eye(2), np.zeros(2)
    window, failures, out = [], 0, []
    loop_start = time.perf_counter()
    for p in positions:
        p_corr = rot_acc @ p + trans_acc
        window.append(p_corr)
        if len(window) > m_max:
            window.pop(0)
        w = np.array(window)
        path = np.linalg.norm(np.diff(w, axis=0), axis=1).sum() if len(w) > 1 else 0.0
        if len(w) < m_min or path < L_MIN:
            out.append(p_corr)
            continue
        s, q = matcher(w, tree, lanes, n)
        e = np.inf
        if len(s) >= ETA * len(w) and len(s) >= 2:
            r, t, e = trimmed_icp(s, q)
        if e < epsilon:
            rot_acc, trans_acc = r @ rot_acc, r @ trans_acc + t
            window = list(w @ r.T + t)
            p_corr = r @ p_corr + t
            failures = 0
        else:
            window.pop(0)
            failures += 1
            if failures > e_max:
                window = window[len(window) - (m_min - 1):]
                failures = 0
        out.append(p_corr)
    loop_s = time.perf_counter() - loop_start
    np.savetxt(out_path, np.array(out), fmt="%.9f")
    total_s = time.perf_counter() - START
    print(f"total_us={total_s * 1e6:.0f} loop_us_per_pose={loop_s * 1e6 / len(positions):.1f}")


if __name__ == "__main__":
    main()
