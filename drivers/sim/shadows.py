"""Cast shadows of the terrain on itself: a sun-visibility map on the heightfield's nodes.

The world's ground is lit by a sun far away, so whether a node sees it depends on the terrain
only, not on the camera: one map per scene and sun, sampled by the renderer like the albedo.
The heightfield is resampled into a frame whose columns run away from the sun, then one sweep
along the columns carries the highest shadow line (a horizon dropping ``cell * tan(elevation)``
per column); nodes below it are in shadow. That is the ray march toward the sun for every node
at once, in O(nodes) numpy work (one vector operation per column), instead of per-pixel marches
of hundreds of steps. Objects (walls, the rover, the target) neither cast nor receive shadows
here: they are not part of the heightfield.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

_FAR_BELOW = np.float32(-1e6)


def sunlit_map(heights: np.ndarray, cell: float, azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Share of each node that sees the sun (float32 0..1, same shape as ``heights``).

    ``heights`` rows run along +y and columns along +x (the heightfield's layout); the sun sits
    at ``azimuth_deg`` (CCW from +x) and ``elevation_deg``. Edges are softened over about one
    cell by the resampling, which stands in for the penumbra.
    """
    h = np.asarray(heights, np.float32)
    ny, nx = h.shape
    az = math.radians(azimuth_deg)
    sx, sy = math.cos(az), math.sin(az)  # toward the sun, in grid units (col, row)
    # Rotated frame: u runs away from the sun, v across; a grid node (x, y) relative to the
    # centre has u = -(sx x + sy y), v = -sy x + sx y.
    cx, cy = (nx - 1) / 2.0, (ny - 1) / 2.0
    corners = np.array([[0, 0], [nx - 1, 0], [0, ny - 1], [nx - 1, ny - 1]], np.float64) - (cx, cy)
    us = -(sx * corners[:, 0] + sy * corners[:, 1])
    vs = -sy * corners[:, 0] + sx * corners[:, 1]
    u0, v0 = math.floor(us.min()) - 1, math.floor(vs.min()) - 1
    nu, nv = math.ceil(us.max()) - u0 + 2, math.ceil(vs.max()) - v0 + 2
    uu, vv = np.meshgrid(np.arange(nu, dtype=np.float32) + u0, np.arange(nv, dtype=np.float32) + v0)
    # back to grid coordinates: x = -sx u - sy v, y = -sy u + sx v
    map_x = (-sx * uu - sy * vv + cx).astype(np.float32)
    map_y = (-sy * uu + sx * vv + cy).astype(np.float32)
    # beyond the grid the ground continues at its edge height (a cliff at the border would
    # shadow the edge rows)
    rot = cv2.remap(h, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    del map_x, map_y, uu, vv
    drop = np.float32(cell * math.tan(math.radians(elevation_deg)))
    horizon = np.full(nv, _FAR_BELOW, np.float32)
    lit = np.empty_like(rot)
    cols = np.ascontiguousarray(rot.T)  # one row per u: contiguous sweeps
    out = lit.T.copy()
    for k in range(nu):
        z = cols[k]
        # soft edge over one drop: fully lit when the node is above the horizon by half a drop
        out[k] = np.clip(0.5 + (z - horizon) / drop, 0.0, 1.0)
        np.maximum(horizon, z, out=horizon)
        horizon -= drop
    lit = np.ascontiguousarray(out.T)
    # Sample the rotated map at every grid node.
    gx, gy = np.meshgrid(np.arange(nx, dtype=np.float64) - cx, np.arange(ny, dtype=np.float64) - cy)
    mu = (-(sx * gx + sy * gy) - u0).astype(np.float32)
    mv = (-sy * gx + sx * gy - v0).astype(np.float32)
    return cv2.remap(lit, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float32)
