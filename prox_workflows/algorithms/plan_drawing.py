"""The plan drawn: the planning image in colours, the A* path, the waypoints and the local map's
border over it with a legend, and a plan or a traverse over the ortho-image."""

from __future__ import annotations

import cv2
import numpy as np

from rvs_params.hazard import HAZARDOUS, UNDEFINED

from ..grid import GridGeometry
from ..mapview import Marks
from .plan_maps import PlanningImage

GREEN = (0, 200, 0)
DIM_GREEN = (0, 110, 0)
BLUE = (0, 0, 255)
RED = (220, 0, 0)
ORANGE = (255, 140, 0)
UNKNOWN_TAN = (205, 190, 150)
MARGIN_SLATE = (95, 95, 120)

LEGEND = ("green: A* path (dim beyond the cut)", "blue: waypoints", "black: hazard",
           "slate: rover radius + margin", "tan: unknown ground", "orange: local map border",
           "grey: slope cost (darker = steeper)")


def _scale_for(shape: tuple[int, int], target: int = 800, limit: int = 4000) -> int:
    return max(1, min(target // max(shape), limit // max(shape)))


def plan_map_rgb(image: PlanningImage) -> np.ndarray:
    """The planning image as RGB: slope cost in grey (white flat, darker steeper), hazards black,
    the rover margin slate, unknown ground tan (seed 000 figs. 54-55)."""
    c = np.nan_to_num(image.env_cost.astype(np.float64), nan=0.0, posinf=1.0)
    grey = (255 - 200 * np.clip(c, 0.0, 1.0)).astype(np.uint8)
    rgb = np.repeat(grey[:, :, None], 3, axis=2)
    rgb[image.hazard == UNDEFINED] = UNKNOWN_TAN
    rgb[image.blocked] = MARGIN_SLATE
    rgb[image.hazard == HAZARDOUS] = (0, 0, 0)
    return rgb


def draw_plan(rgb: np.ndarray, geometry: GridGeometry, path: np.ndarray | None, waypoints: np.ndarray | None,
              cut: int | None = None, local: np.ndarray | None = None, legend: bool = True) -> np.ndarray:
    """An RGB map (on ``geometry``) enlarged for viewing, with the A* path in green (dim after
    ``cut``), the waypoints in blue and, if given, the border of the ``local`` mask in orange."""
    s = _scale_for(rgb.shape[:2])
    out = cv2.resize(rgb, (rgb.shape[1] * s, rgb.shape[0] * s), interpolation=cv2.INTER_NEAREST)
    out = np.ascontiguousarray(out)
    thick = max(1, s // 2)

    def px(xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        col = (xy[:, 0] - geometry.xmin) / geometry.cell * s
        row = (geometry.ymax - xy[:, 1]) / geometry.cell * s
        return np.round(np.stack([col, row], axis=1) * 16).astype(np.int32)  # 4 bits of sub-pixel

    if local is not None and local.any():
        mask = cv2.resize(local.astype(np.uint8), (out.shape[1], out.shape[0]), interpolation=cv2.INTER_NEAREST)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(out, contours, -1, ORANGE, 1)
    if path is not None and len(path) > 1:
        cut = len(path) if cut is None else cut
        if cut < len(path):
            cv2.polylines(out, [px(path[max(cut - 1, 0):])], False, DIM_GREEN, thick, cv2.LINE_AA, shift=4)
        cv2.polylines(out, [px(path[:cut])], False, GREEN, thick + 1, cv2.LINE_AA, shift=4)
    if path is not None and len(path):
        cv2.circle(out, tuple(int(v) for v in px(path[0])[0]), 6 * 16, GREEN, 2, cv2.LINE_AA, shift=4)
        gx, gy = (int(v) for v in px(path[-1])[0])
        d = 6 * 16
        cv2.line(out, (gx - d, gy - d), (gx + d, gy + d), RED, 2, cv2.LINE_AA, shift=4)
        cv2.line(out, (gx - d, gy + d), (gx + d, gy - d), RED, 2, cv2.LINE_AA, shift=4)
    if waypoints is not None and len(waypoints):
        pts = px(waypoints)
        if len(pts) > 1:
            cv2.polylines(out, [pts], False, BLUE, 1, cv2.LINE_AA, shift=4)
        for p in pts:
            cv2.circle(out, (int(p[0]), int(p[1])), max(3, min(6, s // 2)) * 16, BLUE, -1, cv2.LINE_AA, shift=4)
    if legend:
        out = _with_legend(out)
    return out


def _with_legend(img: np.ndarray) -> np.ndarray:
    line = 18
    if img.shape[1] < 340:
        img = np.concatenate([img, np.full((img.shape[0], 340 - img.shape[1], 3), 255, np.uint8)], axis=1)
    panel = np.full((line * len(LEGEND) + 8, img.shape[1], 3), 255, np.uint8)
    for i, text in enumerate(LEGEND):
        cv2.putText(panel, text, (6, line * (i + 1)), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([img, panel], axis=0)


def ortho_figure(ortho: np.ndarray, geometry: GridGeometry, title: str, marks: Marks) -> np.ndarray:
    """The ortho-image with a plan or a traverse drawn over it, as an operator-ready figure whose
    legend names exactly what is drawn (the ortho's own colours mean only brightness)."""
    from ..mapview import Style, figure, layer_rgba

    rgba, legend = layer_rgba(np.asarray(ortho), Style("grey"), geometry.cell)
    return figure(rgba, geometry, legend, title, marks)
