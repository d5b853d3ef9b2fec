"""Terrain albedo from real Mars ground: a seamless texture quilted from navigation-camera frames.

Stereo matches texture, so the simulator's accuracy figures are only as honest as its texture:
the procedural speckle is isotropic fractal noise, real regolith is not (bedrock cracks, pebbles,
drift). :func:`quilt` builds a periodic tile out of many small patches cut from real frames (the
NASA navcam frames in ``../shared/realdata/images``), never stretching one frame over the ground:

- each frame's slow shading (the sun on slopes, the lens falloff) is divided out, leaving the
  relative reflectance at the scales a patch holds;
- patches in the mast's shadow (dark) or in the sky (no texture) are refused;
- patches (random frame, place, quarter turn and mirror) are laid on a lattice at half their size
  with sine windows whose squares sum to one across the overlaps, wrapping around the tile's
  edges, so the blend keeps the frames' contrast everywhere (a plain average would halve the
  variance between patch centres) and the tile repeats without seams.

The result ships as ``drivers/sim/data/mars_albedo.png`` (8-bit, 128 = mean reflectance), made by
``python -m tools.mars_albedo``; :func:`load_texture` reads it as relative reflectance (mean 1).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

MID = 128.0  # the PNG value of mean reflectance
SCALE = 160.0  # PNG counts per unit of relative reflectance: 1.0 -> 128, 0.2 -> 0, 1.8 -> 255


def relative_reflectance(frame: np.ndarray, sigma_px: float = 24.0) -> np.ndarray:
    """The frame divided by its own blurred copy: the slow shading removed, mean about 1."""
    f = frame.astype(np.float32) + 1.0
    slow = cv2.GaussianBlur(f, (0, 0), sigma_px)
    return f / slow


def usable_patches(frame: np.ndarray, patch: int, step: int, near: float = 0.5) -> list[tuple[int, int]]:
    """Top-left corners of patches on real lit ground: in the lower ``near`` share of the frame
    (the near field, seen least obliquely: far-field patches are squashed several times
    vertically by perspective, which would stretch the ground's texture into streaks), neither in
    a shadow (the mast's: mean below 60 % of the frame's bright ground) nor sky or blur
    (fine-scale texture below 40 % of the frame's typical)."""
    f = frame.astype(np.float32)
    fine = f - cv2.GaussianBlur(f, (0, 0), 2.0)
    ground_level = float(np.percentile(f, 75))
    out: list[tuple[int, int]] = []
    stats = []
    for r in range(int(f.shape[0] * (1.0 - near)), f.shape[0] - patch + 1, step):
        for c in range(0, f.shape[1] - patch + 1, step):
            stats.append((r, c, float(f[r:r + patch, c:c + patch].mean()),
                          float(fine[r:r + patch, c:c + patch].std())))
    texture_level = float(np.median([s[3] for s in stats]))
    for r, c, mean, tex in stats:
        if mean >= 0.6 * ground_level and tex >= 0.4 * texture_level:
            out.append((r, c))
    return out


def quilt(frames: list[np.ndarray], size: int = 512, patch: int = 64, seed: int = 13) -> np.ndarray:
    """A ``size`` x ``size`` periodic tile of relative reflectance (float32, mean 1) blended from
    ``patch``-pixel patches of the frames (grey, any size); see the module docstring."""
    if size % (patch // 2):
        raise ValueError("size must be a multiple of half the patch")
    rng = np.random.default_rng(seed)
    rel = [relative_reflectance(f) for f in frames]
    pools = [usable_patches(f, patch, patch // 4) for f in frames]
    choices = [(i, rc) for i, pool in enumerate(pools) for rc in pool]
    if not choices:
        raise ValueError("no usable ground patch in the frames")
    half = patch // 2
    w1 = np.sin(np.pi * (np.arange(patch) + 0.5) / patch).astype(np.float32)  # sin^2 + cos^2 = 1 at 50 % overlap
    win = np.outer(w1, w1)
    acc = np.zeros((size, size), np.float32)
    for r0 in range(0, size, half):
        for c0 in range(0, size, half):
            i, (r, c) = choices[int(rng.integers(len(choices)))]
            p = rel[i][r:r + patch, c:c + patch]
            p = np.rot90(p, int(rng.integers(4)))
            if rng.integers(2):
                p = p[:, ::-1]
            dev = (p - p.mean()) * win
            rows = (np.arange(patch) + r0) % size
            cols = (np.arange(patch) + c0) % size
            acc[np.ix_(rows, cols)] += dev
    return (1.0 + acc).astype(np.float32)


def encode(texture: np.ndarray) -> np.ndarray:
    """Relative reflectance to the shipped 8-bit form."""
    return np.clip(np.rint(MID + SCALE * (texture - 1.0)), 0, 255).astype(np.uint8)


def load_texture(path: str | Path) -> np.ndarray:
    """The shipped 8-bit texture as relative reflectance (float32, mean about 1)."""
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise FileNotFoundError(f"cannot read albedo texture {path}")
    return (1.0 + (img.astype(np.float32) - MID) / SCALE).astype(np.float32)


def sample_periodic(texture: np.ndarray, x: np.ndarray, y: np.ndarray, texel: float) -> np.ndarray:
    """The texture at world (x, y) (metres), ``texel`` metres per texture pixel, wrapping around.

    Two samplings at different angles and scales blended by a slow mask, so a 5 m tile does not
    show as a repeating grid over a 20 m yard."""
    n = texture.shape[0]
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)

    def at(fu: np.ndarray, fv: np.ndarray) -> np.ndarray:
        return cv2.remap(texture, np.mod(fu, n).astype(np.float32), np.mod(fv, n).astype(np.float32),
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)

    a = at(x / texel, y / texel)
    c, s = np.cos(0.61), np.sin(0.61)
    t2 = texel * 1.37
    b = at((c * x + s * y) / t2 + 101.3, (-s * x + c * y) / t2 + 57.9)
    # slow mask, period ~7-11 m: which sampling shows where
    m = 0.5 + 0.5 * np.sin(x * 0.83 + 1.3 * np.sin(y * 0.57)) * np.cos(y * 0.71 + 0.9 * np.sin(x * 0.49))
    m = np.clip(1.5 * (m - 0.5) + 0.5, 0.0, 1.0).astype(np.float32)
    # blend deviations with weights whose squares sum to 1: contrast stays that of the frames
    wa = np.sqrt(m)
    wb = np.sqrt(1.0 - m)
    return (1.0 + wa * (a - 1.0) + wb * (b - 1.0)).astype(np.float32)
