"""D* Lite's inner loops (Koenig & Likhachev 2002, the optimised version of their fig. 4) over a
flattened, padded grid, in the subset of Python numba compiles. :mod:`.replan` owns the state
and calls these; they live in their own module so that importing :mod:`.replan` does not import
numba (~0.3 s) and so that the helpers can call one another both compiled and, without numba,
as plain Python.

State (all arrays over the padded grid, whose outer ring is blocked so that a neighbour index
never leaves the array):

- ``k``: float64 cost per unit length (inf blocked), as :func:`.astar.astar_grid` takes it;
- ``g``, ``rhs``: int64 fixed-point cost to the goal and its one-step lookahead (``INF`` none);
- the open list, an indexed binary heap: ``h1``, ``h2`` (the two-part key), ``hc`` (the cell)
  and ``pos`` (each cell's position in the heap, -1 when not in it); ``meta[0]`` is its size,
  ``meta[1]`` D* Lite's ``km`` (the heuristic's drift as the start moves), ``meta[2:4]`` the
  start's row and column;
- ``nb``: (5, 8) int64, the neighbour offsets; for a diagonal, the two orthogonal cells it
  passes between (zero for orthogonal steps); the row and column steps. ``7 - d`` reverses ``d``;
- ``ip``: int64 (width, corner rule, heuristic type, h per orthogonal cell, h per diagonal);
- ``fp``: float64 (orth step, diag step, share, 1 - share, h per euclidean cell).

The step cost is computed exactly as the A* kernel computes it, floored to an integer, and at
least one unit: D* Lite needs positive edges for its path read-out to descend strictly.
"""

from __future__ import annotations

import math

import numpy as np

from rvs_params.jit import jit

INF = 1 << 62  # no path; every real cost stays below 2**61 (see replan._Scale)

_jit = jit()
_inline = jit(inline="always")


@_jit
def heuristic(a: int, b: int, ip: np.ndarray, fp: np.ndarray) -> int:
    """The lower bound on the cost between cells ``a`` and ``b``; consistent by construction of
    its weights (replan clamps them below the cheapest step)."""
    w = ip[0]
    ar = a // w
    br = b // w
    dr = abs(ar - br)
    dc = abs((a - ar * w) - (b - br * w))
    ht = ip[2]
    if ht == 2:
        mn = min(dr, dc)
        return ip[3] * (max(dr, dc) - mn) + ip[4] * mn
    if ht == 0:
        return np.int64(fp[4] * math.sqrt(dr * dr + dc * dc))
    return ip[3] * max(dr, dc)


@_inline
def step_cost(k: np.ndarray, u: int, d: int, nb: np.ndarray, fp: np.ndarray, corner: bool) -> int:
    """The fixed-point cost of the step from ``u`` in direction ``d``; INF when it is refused."""
    v = u + nb[0, d]
    ku = k[u]
    kv = k[v]
    if ku == np.inf or kv == np.inf:
        return INF
    o = nb[1, d]
    if o != 0:
        if corner and (k[u + o] == np.inf or k[u + nb[2, d]] == np.inf):
            return INF
        c = np.int64(fp[1] * (fp[2] * ku + fp[3] * kv))
    else:
        c = np.int64(fp[0] * (fp[2] * ku + fp[3] * kv))
    if c < 1:
        return np.int64(1)
    return c


@_inline
def _less(a1, a2, ac, b1, b2, bc):
    return a1 < b1 or (a1 == b1 and (a2 < b2 or (a2 == b2 and ac < bc)))


@_jit
def _sift_up(i, h1, h2, hc, pos):
    x1 = h1[i]
    x2 = h2[i]
    xc = hc[i]
    while i > 0:
        p = (i - 1) >> 1
        if _less(x1, x2, xc, h1[p], h2[p], hc[p]):
            h1[i] = h1[p]
            h2[i] = h2[p]
            hc[i] = hc[p]
            pos[hc[i]] = i
            i = p
        else:
            break
    h1[i] = x1
    h2[i] = x2
    hc[i] = xc
    pos[xc] = i


@_jit
def _sift_down(i, size, h1, h2, hc, pos):
    x1 = h1[i]
    x2 = h2[i]
    xc = hc[i]
    while True:
        c = 2 * i + 1
        if c >= size:
            break
        c2 = c + 1
        if c2 < size and _less(h1[c2], h2[c2], hc[c2], h1[c], h2[c], hc[c]):
            c = c2
        if _less(h1[c], h2[c], hc[c], x1, x2, xc):
            h1[i] = h1[c]
            h2[i] = h2[c]
            hc[i] = hc[c]
            pos[hc[i]] = i
            i = c
        else:
            break
    h1[i] = x1
    h2[i] = x2
    hc[i] = xc
    pos[xc] = i


@_jit
def _put(u, k1, k2, h1, h2, hc, pos, meta):
    i = pos[u]
    if i < 0:
        i = meta[0]
        meta[0] = i + 1
        h1[i] = k1
        h2[i] = k2
        hc[i] = u
        _sift_up(i, h1, h2, hc, pos)
        return
    up = _less(k1, k2, u, h1[i], h2[i], u)
    h1[i] = k1
    h2[i] = k2
    if up:
        _sift_up(i, h1, h2, hc, pos)
    else:
        _sift_down(i, meta[0], h1, h2, hc, pos)


@_jit
def _remove(u, h1, h2, hc, pos, meta):
    i = pos[u]
    pos[u] = -1
    size = meta[0] - 1
    meta[0] = size
    if i == size:
        return
    h1[i] = h1[size]
    h2[i] = h2[size]
    hc[i] = hc[size]
    pos[hc[i]] = i
    if i > 0 and _less(h1[i], h2[i], hc[i], h1[(i - 1) >> 1], h2[(i - 1) >> 1], hc[(i - 1) >> 1]):
        _sift_up(i, h1, h2, hc, pos)
    else:
        _sift_down(i, size, h1, h2, hc, pos)


@_inline
def _h_from_start(ur, uc, meta, ip, fp):
    """heuristic(start, u) from u's row and column, the start's cached in meta[2], meta[3]:
    no integer division in the inner loop."""
    dr = abs(ur - meta[2])
    dc = abs(uc - meta[3])
    ht = ip[2]
    if ht == 2:
        if dr < dc:
            return ip[3] * (dc - dr) + ip[4] * dr
        return ip[3] * (dr - dc) + ip[4] * dc
    if ht == 0:
        return np.int64(fp[4] * math.sqrt(dr * dr + dc * dc))
    return ip[3] * max(dr, dc)


@_inline
def _key(u, ur, uc, g, rhs, start, meta, ip, fp):
    m = min(g[u], rhs[u])
    if m >= INF:
        return np.int64(INF), np.int64(INF)
    if u == start:
        return m + meta[1], m
    return m + _h_from_start(ur, uc, meta, ip, fp) + meta[1], m


@_jit
def _update_vertex(u, ur, uc, g, rhs, start, h1, h2, hc, pos, meta, ip, fp):
    if g[u] != rhs[u]:
        k1, k2 = _key(u, ur, uc, g, rhs, start, meta, ip, fp)
        _put(u, k1, k2, h1, h2, hc, pos, meta)
    elif pos[u] >= 0:
        _remove(u, h1, h2, hc, pos, meta)


@_inline
def _lookahead(s, k, g, nb, fp, corner):
    """rhs(s) = min over successors s' of c(s, s') + g(s')."""
    if k[s] == np.inf:
        return np.int64(INF)
    best = np.int64(INF)
    for d in range(8):
        gv = g[s + nb[0, d]]
        if gv >= INF:
            continue
        c = step_cost(k, s, d, nb, fp, corner)
        if c < INF and c + gv < best:
            best = c + gv
    return best


@_jit
def set_start(meta: np.ndarray, ip: np.ndarray, start: int) -> None:
    meta[2] = start // ip[0]
    meta[3] = start - meta[2] * ip[0]


@_jit
def initialise(g: np.ndarray, rhs: np.ndarray, h1: np.ndarray, h2: np.ndarray, hc: np.ndarray, pos: np.ndarray,
               meta: np.ndarray, ip: np.ndarray, fp: np.ndarray, start: int, goal: int) -> None:
    g[:] = INF
    rhs[:] = INF
    pos[:] = -1
    meta[0] = 0
    meta[1] = 0
    set_start(meta, ip, start)
    rhs[goal] = 0
    _put(goal, heuristic(start, goal, ip, fp), np.int64(0), h1, h2, hc, pos, meta)


@_jit
def compute_shortest_path(k: np.ndarray, g: np.ndarray, rhs: np.ndarray, h1: np.ndarray, h2: np.ndarray,
                          hc: np.ndarray, pos: np.ndarray, meta: np.ndarray, nb: np.ndarray, ip: np.ndarray,
                          fp: np.ndarray, start: int, goal: int) -> int:
    """ComputeShortestPath: expand until the start is locally consistent and no open key is
    below its key. Returns the number of cells expanded."""
    corner = ip[1] != 0
    w = ip[0]
    expanded = 0
    while meta[0] > 0:
        t1 = h1[0]
        t2 = h2[0]
        u = hc[0]
        s1, s2 = _key(start, meta[2], meta[3], g, rhs, start, meta, ip, fp)
        if not (t1 < s1 or (t1 == s1 and t2 < s2)) and rhs[start] <= g[start]:
            break
        ur = u // w
        uc = u - ur * w
        n1, n2 = _key(u, ur, uc, g, rhs, start, meta, ip, fp)
        if t1 < n1 or (t1 == n1 and t2 < n2):  # a key from before the start moved: re-queue
            _put(u, n1, n2, h1, h2, hc, pos, meta)
            continue
        expanded += 1
        if g[u] > rhs[u]:  # overconsistent: settle it and offer it to the predecessors
            gu = rhs[u]
            g[u] = gu
            _remove(u, h1, h2, hc, pos, meta)
            for d in range(8):
                s = u + nb[0, d]
                if s == goal or k[s] == np.inf:
                    continue
                c = step_cost(k, s, 7 - d, nb, fp, corner)
                if c < INF and c + gu < rhs[s]:
                    rhs[s] = c + gu
                    _update_vertex(s, ur + nb[3, d], uc + nb[4, d], g, rhs, start, h1, h2, hc, pos, meta, ip, fp)
        else:  # underconsistent: forget it, and re-derive the predecessors that relied on it
            gold = g[u]
            g[u] = INF
            _update_vertex(u, ur, uc, g, rhs, start, h1, h2, hc, pos, meta, ip, fp)
            for d in range(8):
                s = u + nb[0, d]
                if s == goal or k[s] == np.inf:
                    continue
                c = step_cost(k, s, 7 - d, nb, fp, corner)
                if c < INF and rhs[s] == c + gold:
                    rhs[s] = _lookahead(s, k, g, nb, fp, corner)
                    _update_vertex(s, ur + nb[3, d], uc + nb[4, d], g, rhs, start, h1, h2, hc, pos, meta, ip, fp)
    return expanded


@_jit
def update_cells(k: np.ndarray, g: np.ndarray, rhs: np.ndarray, h1: np.ndarray, h2: np.ndarray, hc: np.ndarray,
                 pos: np.ndarray, meta: np.ndarray, nb: np.ndarray, ip: np.ndarray, fp: np.ndarray, start: int,
                 goal: int, cells: np.ndarray, values: np.ndarray) -> None:
    """Set ``k[cells] = values`` and re-derive rhs of every cell whose outgoing steps may have
    changed: the changed cells and their 8 neighbours (steps into a changed cell, and diagonals
    passing its corner under the corner rule)."""
    corner = ip[1] != 0
    w = ip[0]
    for i in range(cells.shape[0]):
        k[cells[i]] = values[i]
    for i in range(cells.shape[0]):
        x = cells[i]
        xr = x // w
        xc = x - xr * w
        for d in range(9):
            if d == 8:
                u, ur, uc = x, xr, xc
            else:
                u, ur, uc = x + nb[0, d], xr + nb[3, d], xc + nb[4, d]
            if u == goal:
                continue
            r = _lookahead(u, k, g, nb, fp, corner)
            if r != rhs[u]:
                rhs[u] = r
                _update_vertex(u, ur, uc, g, rhs, start, h1, h2, hc, pos, meta, ip, fp)


@_jit
def read_path(k: np.ndarray, g: np.ndarray, nb: np.ndarray, ip: np.ndarray, fp: np.ndarray, start: int, goal: int,
              out: np.ndarray) -> int:
    """Follow argmin c(u, v) + g(v) from the start to the goal into ``out``; ties go to the
    neighbour nearest the goal, then the lower index. Returns the number of cells, -1 if the
    descent breaks off (which would be a bug: every step descends strictly)."""
    corner = ip[1] != 0
    w = ip[0]
    gr = goal // w
    gc = goal - gr * w
    u = start
    out[0] = u
    n = 1
    while u != goal:
        best = -1
        bv = np.int64(INF)
        bd = np.int64(0)
        for d in range(8):
            v = u + nb[0, d]
            gv = g[v]
            if gv >= INF:
                continue
            c = step_cost(k, u, d, nb, fp, corner)
            if c >= INF:
                continue
            val = c + gv
            vr = v // w
            d2 = (vr - gr) * (vr - gr) + (v - vr * w - gc) * (v - vr * w - gc)
            if val < bv or (val == bv and (d2 < bd or (d2 == bd and v < best))):
                best = v
                bv = val
                bd = d2
        if best < 0 or n >= out.shape[0]:
            return -1
        out[n] = best
        n += 1
        u = best
    return n


@_jit
def cost_to_go(k: np.ndarray, g: np.ndarray, nb: np.ndarray, fp: np.ndarray, ip: np.ndarray, cells: np.ndarray,
               out: np.ndarray) -> None:
    """The one-step lookahead of each cell: min over its successors of c + g, the cost to the
    goal as the current search knows it (INF where it has not reached)."""
    corner = ip[1] != 0
    for i in range(cells.shape[0]):
        out[i] = _lookahead(cells[i], k, g, nb, fp, corner)
