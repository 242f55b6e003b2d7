#!/usr/bin/env python3
"""Peer of `chirpmap map` for issue 14's side-by-side table: map echoes with numpy.

Two methods:

* ``rowspan``: chirpmap's own row-span rasteriser (crates/chirpmap-core/src/raster.rs,
  paper Algorithm 1's "cells the ellipse enters"), vectorised over chunks of ellipses: per
  row the crossings of its two grid lines give the two arcs' column spans; cells are
  accumulated with ``np.bincount``. Same formulas in float64 as the Rust code, so with unit
  weights the grid equals chirpmap's ``map.npy`` cell for cell (checked with --compare).
* ``band``: a competent numpy band test: per ellipse, every cell of its bounding box whose
  centre's focal excess |p-S| + |p-L| - (D + dd) is within half a cell diagonal is marked.
  Approximate (it is not the "entered cells" set) and slow; run it on a subset (--limit).

Both then threshold (keep the top 10 % of non-zero cells and those above 1 % of the
maximum) and find local maxima within 5 m with scipy.ndimage.maximum_filter (plateaus are
not thinned as chirpmap does), and save the grid as .npy. No figure is drawn.
"""
import argparse
import sys

import numpy as np
from scipy import ndimage


def ellipses(e):
    s, l, dd = e[:, 0:2], e[:, 2:4], e[:, 4]
    d = l - s
    dist = np.hypot(d[:, 0], d[:, 1])
    a = 0.5 * (dist + dd)
    b = 0.5 * np.sqrt(dd * (2.0 * dist + dd))
    c, sn = d[:, 0] / dist, d[:, 1] / dist
    a2, b2 = a * a, b * b
    qa = a2 * sn * sn + b2 * c * c
    qb = 2.0 * (b2 - a2) * sn * c
    qc = a2 * c * c + b2 * sn * sn
    centre = 0.5 * (s + l)
    return a, b, qa, qb, qc, centre


def rowspan(e, w, bounds, cell, chunk=4000):
    x0, y0, x1, y1 = bounds
    nx, ny = int(np.ceil((x1 - x0) / cell)), int(np.ceil((y1 - y0) / cell))
    grid = np.zeros(nx * ny)
    for k in range(0, len(e), chunk):
        ek, wk = e[k:k + chunk], w[k:k + chunk]
        a, b, qa, qb, qc, centre = ellipses(ek)
        inv_w = 1.0 / cell
        hx, hy = np.sqrt(qc) * inv_w, np.sqrt(qa) * inv_w
        cx, cy = (centre[:, 0] - x0) * inv_w, (centre[:, 1] - y0) * inv_w
        keep = ~((cx + hx < 0) | (cy + hy < 0) | (cx - hx >= nx) | (cy - hy >= ny))
        a, b, qa, qb, qc, hx, hy, cx, cy, wk = (v[keep] for v in (a, b, qa, qb, qc, hx, hy, cx, cy, wk))
        with np.errstate(divide="ignore", invalid="ignore"):
            y_right = np.where(qc > 0, -qb * hx / (2.0 * qc), 0.0)
            k_mid = np.where(qa > 0, -qb / (2.0 * qa), 0.0)
            k_half = np.where(qa > 0, a * b / qa, 0.0)
        qa_c = qa * inv_w * inv_w
        j_bottom, j_top = np.floor(cy - hy), np.floor(cy + hy)
        j_left, j_right = np.floor(cy - y_right), np.floor(cy + y_right)
        j_first, j_last = np.maximum(j_bottom, 0), np.minimum(j_top, ny - 1)
        x_left, x_right = np.floor(cx + -hx), np.floor(cx + hx)
        # One entry per (ellipse, row).
        n_rows = (j_last - j_first + 1).astype(np.int64)
        el = np.repeat(np.arange(len(cx)), n_rows)
        j = j_first[el] + (np.arange(n_rows.sum()) - np.repeat(np.cumsum(n_rows) - n_rows, n_rows))

        def crossing(y):
            half = k_half[el] * np.sqrt(np.maximum(qa_c[el] - y * y, 0.0))
            mid = k_mid[el] * y
            return (np.floor(cx[el] + np.maximum(mid - half, -hx[el])),
                    np.floor(cx[el] + np.minimum(mid + half, hx[el])))

        bl, br = crossing(j - cy[el])
        tl, tr = crossing((j + 1.0) - cy[el])
        lo1, hi1 = np.minimum(bl, tl), np.maximum(bl, tl)
        lo2, hi2 = np.minimum(br, tr), np.maximum(br, tr)
        is_b, is_t = j == j_bottom[el], j == j_top[el]
        single = is_b | is_t
        s_lo = np.where(is_b & is_t, x_left[el], np.where(is_b, tl, bl))
        s_hi = np.where(is_b & is_t, x_right[el], np.where(is_b, tr, br))
        lo1, hi1 = np.where(single, s_lo, lo1), np.where(single, s_hi, hi1)
        lo2, hi2 = np.where(single, nx + 1.0, lo2), np.where(single, -1.0, hi2)
        at_left, at_right = j == j_left[el], j == j_right[el]
        lo1 = np.where(at_left, x_left[el], lo1)
        hi1 = np.where(at_right & single, x_right[el], hi1)
        hi2 = np.where(at_right & ~single, x_right[el], hi2)
        lo2 = np.maximum(lo2, hi1 + 1.0)
        starts, lens, weights = [], [], []
        for lo, hi in ((lo1, hi1), (lo2, hi2)):
            lo, hi = np.maximum(lo, 0), np.minimum(hi, nx - 1)
            ok = lo <= hi
            starts.append((j[ok] * nx + lo[ok]).astype(np.int64))
            lens.append((hi[ok] - lo[ok] + 1).astype(np.int64))
            weights.append(wk[el[ok]])
        starts, lens, weights = np.concatenate(starts), np.concatenate(lens), np.concatenate(weights)
        total = lens.sum()
        idx = np.repeat(starts - (np.cumsum(lens) - lens), lens) + np.arange(total)
        grid += np.bincount(idx, weights=np.repeat(weights, lens), minlength=nx * ny)
    return grid.reshape(ny, nx)


def band(e, w, bounds, cell):
    x0, y0, x1, y1 = bounds
    nx, ny = int(np.ceil((x1 - x0) / cell)), int(np.ceil((y1 - y0) / cell))
    grid = np.zeros((ny, nx))
    xs, ys = x0 + (np.arange(nx) + 0.5) * cell, y0 + (np.arange(ny) + 0.5) * cell
    a, _, qa, _, qc, centre = ellipses(e)
    tol = 0.5 * cell * np.sqrt(2.0)
    for k in range(len(e)):
        hx, hy = np.sqrt(qc[k]), np.sqrt(qa[k])
        i0, i1 = np.searchsorted(xs, centre[k, 0] - hx - cell), np.searchsorted(xs, centre[k, 0] + hx + cell)
        j0, j1 = np.searchsorted(ys, centre[k, 1] - hy - cell), np.searchsorted(ys, centre[k, 1] + hy + cell)
        if i0 >= i1 or j0 >= j1:
            continue
        px, py = xs[None, i0:i1], ys[j0:j1, None]
        excess = np.hypot(px - e[k, 0], py - e[k, 1]) + np.hypot(px - e[k, 2], py - e[k, 3]) - 2.0 * a[k]
        grid[j0:j1, i0:i1] += np.where(np.abs(excess) <= tol, w[k], 0.0)
    return grid


def highlights(grid, cell, keep_top=0.1, min_of_max=0.01, peak_radius=5.0):
    nz = grid[grid != 0]
    if nz.size == 0:
        return np.zeros((0, 2), dtype=int)
    rank = min(int(np.floor((1.0 - keep_top) * nz.size)), nz.size - 1)
    floor = max(np.partition(nz, rank)[rank], min_of_max * grid.max())
    kept = np.where(grid < floor, 0.0, grid)
    r = int(np.floor(peak_radius / cell + 1e-9))
    wmax = ndimage.maximum_filter(kept, size=2 * r + 1, mode="constant", cval=0.0)
    return np.argwhere((kept > 0) & (kept == wmax))


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("echoes", help="echoes CSV (source_x,source_y,listener_x,listener_y,delta_d[,weight,...])")
    p.add_argument("--bounds", default="-50,-50,50,50")
    p.add_argument("--cell", type=float, default=0.1)
    p.add_argument("--method", choices=["rowspan", "band"], default="rowspan")
    p.add_argument("--limit", type=int, default=0, help="use only the first N echoes")
    p.add_argument("--out", required=True, help="grid as .npy")
    p.add_argument("--compare", help="chirpmap's map.npy to compare cell for cell")
    args = p.parse_args()
    data = np.loadtxt(args.echoes, delimiter=",", skiprows=1, ndmin=2)
    if args.limit:
        data = data[:args.limit]
    w = data[:, 5] if data.shape[1] > 5 else np.ones(len(data))
    bounds = [float(v) for v in args.bounds.split(",")]
    grid = (rowspan if args.method == "rowspan" else band)(data[:, :5], w, bounds, args.cell)
    h = highlights(grid, args.cell)
    np.save(args.out, grid)
    msg = f"{args.method}: {len(data)} echoes, {int(np.count_nonzero(grid))} cells non-zero, {len(h)} highlights"
    if args.compare:
        theirs = np.load(args.compare)
        same = theirs.shape == grid.shape and np.array_equal(theirs, grid)
        msg += f", same map as chirpmap: {'yes' if same else 'no'}"
    print(msg, file=sys.stderr)


if __name__ == "__main__":
    main()
