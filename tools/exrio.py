"""Reading of the EXR files written by render.py (shared by the check/preview tools)."""

import os

import numpy as np


def read_exr(path):
    """{channel name: (H,W) float64 array} of one scanline EXR file."""
    import OpenEXR
    with OpenEXR.File(path, separate_channels=True) as f:
        return {name: np.asarray(ch.pixels, dtype=np.float64) for name, ch in f.channels().items()}


def stack(chs, names):
    return np.stack([chs[n] for n in names], axis=-1)


def frame_paths(directory):
    names = sorted(n for n in os.listdir(directory) if n.startswith('frame_') and n.endswith('.exr'))
    return [os.path.join(directory, n) for n in names]


def load_frame(directory, index):
    """(noisy channels, reference channels or None) of frame `index`."""
    name = 'frame_%04d.exr' % index
    noisy = read_exr(os.path.join(directory, name))
    ref_path = os.path.join(directory, 'ref', name)
    ref = read_exr(ref_path) if os.path.exists(ref_path) else None
    return noisy, ref


def warp_bilinear(img, motion):
    """Fetch img (H,W,C) at pixel centre + motion (H,W,2), bilinear, clamped.

    Returns (warped image, mask of pixels whose source lies inside the image).
    """
    h, w = img.shape[:2]
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    # continuous source position of the pixel centre, then back to index space
    sx = xs + 0.5 + motion[..., 0] - 0.5
    sy = ys + 0.5 + motion[..., 1] - 0.5
    inside = (sx >= 0) & (sx <= w - 1) & (sy >= 0) & (sy <= h - 1)
    sx = np.clip(sx, 0, w - 1)
    sy = np.clip(sy, 0, h - 1)
    x0 = np.minimum(np.floor(sx).astype(int), w - 2 if w > 1 else 0)
    y0 = np.minimum(np.floor(sy).astype(int), h - 2 if h > 1 else 0)
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    fx = (sx - x0)[..., None]
    fy = (sy - y0)[..., None]
    out = ((1 - fx) * (1 - fy) * img[y0, x0] + fx * (1 - fy) * img[y0, x1]
           + (1 - fx) * fy * img[y1, x0] + fx * fy * img[y1, x1])
    return out, inside
