"""A*'s inner loop over a flattened, padded grid, in the subset of Python numba compiles:
:mod:`.astar` owns the search and compiles this on first use, so that importing it does not
import numba (~0.3 s); without numba the same function runs as plain Python."""

from __future__ import annotations

import math

import numpy as np


def astar_kernel(k, width, start, goal, c_orth, c_diag, share, corner, htype, h_lin, h_diag, g, parent):  # noqa: C901
    """A* over a flattened grid ``k`` (per-metre cost factors, inf = blocked) whose outer ring is
    blocked, so a neighbour index never leaves the array. Costs are fixed-point integers: a step
    costs floor(c_step * (share * k[u] + (1 - share) * k[v])), c_step being the step length in
    cost units; H is the octile distance with integer weights (h_lin, h_diag) or h_lin times the
    euclidean / manhattan / chebyshev cell distance, floored. Writes g (int64) and parent;
    returns (found, expanded cells). Written in the subset of Python numba compiles."""
    n = k.shape[0]
    pos = np.full(n, -1, np.int32)  # -1 unseen, -2 closed, >= 0 position in the heap
    cap = 4096
    hf = np.empty(cap, np.int64)  # heap: f
    hk = np.empty(cap, np.int64)  # heap: (squared cell distance to goal << 32) | cell
    offs = np.array((-width - 1, -width, -width + 1, -1, 1, width - 1, width, width + 1), np.int64)
    drow = np.array((-1, -1, -1, 0, 0, 1, 1, 1), np.int64)
    dcol = np.array((-1, 0, 1, -1, 1, -1, 0, 1), np.int64)
    orow = np.array((-width, 0, -width, 0, 0, width, 0, width), np.int64)  # the two cells a
    ocol = np.array((-1, 0, 1, 0, 0, -1, 0, 1), np.int64)  # diagonal step passes between
    mask32 = (1 << 32) - 1
    dmax = (1 << 31) - 1
    rest = 1.0 - share
    gr = goal // width
    gc = goal - gr * width
    sr = start // width
    sc = start - sr * width
    dr = abs(sr - gr)
    dc = abs(sc - gc)
    if htype == 2:
        mn = min(dr, dc)
        h0 = h_lin * (max(dr, dc) - mn) + h_diag * mn
    elif htype == 0:
        h0 = np.int64(h_lin * math.sqrt(dr * dr + dc * dc))
    elif htype == 1:
        h0 = h_lin * (dr + dc)
    else:
        h0 = h_lin * max(dr, dc)
    g[start] = 0
    hf[0] = h0
    hk[0] = (min(dr * dr + dc * dc, dmax) << 32) | start
    pos[start] = 0
    size = 1
    expanded = 0
    found = False
    while size > 0:
        u = hk[0] & mask32
        pos[u] = -2
        size -= 1
        if size > 0:  # the last entry replaces the root and sinks
            lf = hf[size]
            lk = hk[size]
            i = 0
            while True:
                c1 = 2 * i + 1
                if c1 >= size:
                    break
                best = c1
                bf = hf[c1]
                bk = hk[c1]
                c2 = c1 + 1
                if c2 < size:
                    f2 = hf[c2]
                    k2 = hk[c2]
                    if f2 < bf or (f2 == bf and k2 < bk):
                        best = c2
                        bf = f2
                        bk = k2
                if bf < lf or (bf == lf and bk < lk):
                    hf[i] = bf
                    hk[i] = bk
                    pos[bk & mask32] = i
                    i = best
                else:
                    break
            hf[i] = lf
            hk[i] = lk
            pos[lk & mask32] = i
        expanded += 1
        if u == goal:
            found = True
            break
        gu = g[u]
        ku = share * k[u]
        ur = u // width
        uc = u - ur * width
        for d in range(8):
            v = u + offs[d]
            kv = k[v]
            if kv == np.inf:
                continue
            pv = pos[v]
            if pv == -2:
                continue
            if orow[d] != 0:  # diagonal
                if corner and (k[u + orow[d]] == np.inf or k[u + ocol[d]] == np.inf):
                    continue
                ng = gu + np.int64(c_diag * (ku + rest * kv))
            else:
                ng = gu + np.int64(c_orth * (ku + rest * kv))
            if ng < g[v]:
                g[v] = ng
                parent[v] = u
                dr = abs(ur + drow[d] - gr)
                dc = abs(uc + dcol[d] - gc)
                if htype == 2:
                    mn = min(dr, dc)
                    hv = h_lin * (max(dr, dc) - mn) + h_diag * mn
                elif htype == 0:
                    hv = np.int64(h_lin * math.sqrt(dr * dr + dc * dc))
                elif htype == 1:
                    hv = h_lin * (dr + dc)
                else:
                    hv = h_lin * max(dr, dc)
                fv = ng + hv
                kk = (min(dr * dr + dc * dc, dmax) << 32) | v
                if pv < 0:  # new entry at the bottom
                    if size == cap:
                        cap *= 2
                        nf = np.empty(cap, np.int64)
                        nf[:size] = hf[:size]
                        hf = nf
                        nk = np.empty(cap, np.int64)
                        nk[:size] = hk[:size]
                        hk = nk
                    i = size
                    size += 1
                else:  # decrease-key: the entry rises from where it is
                    i = pv
                while i > 0:
                    p = (i - 1) >> 1
                    pf = hf[p]
                    if fv < pf or (fv == pf and kk < hk[p]):
                        hf[i] = pf
                        hk[i] = hk[p]
                        pos[hk[p] & mask32] = i
                        i = p
                    else:
                        break
                hf[i] = fv
                hk[i] = kk
                pos[v] = i
    return found, expanded
