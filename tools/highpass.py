#!/usr/bin/env python3
"""A high-pass view of EXR frames side by side, for structure the eye misses
at normal contrast (grids, streaks, blotches): log luminance minus its 5x5
box mean, times GAIN, around mid-grey, a crop of each frame enlarged.

    tools/.venv/bin/python tools/highpass.py OUT.png FRAME.exr [FRAME.exr ...] \\
        [--crop X Y W H] [--scale 2] [--gain 8]
"""

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from exrio import read_exr, stack  # noqa: E402
from preview import write_png  # noqa: E402


def highpass(path, k=5):
    lum = np.log(stack(read_exr(path), ['R', 'G', 'B']).mean(-1) + 1e-3)
    pad = np.pad(lum, k // 2, mode='edge')
    h, w = lum.shape
    mean = sum(pad[i:i + h, j:j + w] for i in range(k) for j in range(k)) / (k * k)
    return lum - mean


def main():
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('png')
    p.add_argument('frames', nargs='+')
    p.add_argument('--crop', type=int, nargs=4, metavar=('X', 'Y', 'W', 'H'))
    p.add_argument('--scale', type=int, default=2)
    p.add_argument('--gain', type=float, default=8.0)
    a = p.parse_args()
    tiles = []
    for f in a.frames:
        d = highpass(f)
        if a.crop:
            x, y, w, h = a.crop
            d = d[y:y + h, x:x + w]
        t = np.clip(0.5 + a.gain * d, 0, 1)
        tiles += [np.repeat(t[..., None], 3, -1), np.ones((t.shape[0], 2, 3))]
    sheet = np.concatenate(tiles[:-1], 1)
    sheet = np.repeat(np.repeat(sheet, a.scale, 0), a.scale, 1)
    write_png(a.png, (sheet * 255 + 0.5).astype(np.uint8))
    print('wrote %s (%dx%d)' % (a.png, sheet.shape[1], sheet.shape[0]))


if __name__ == '__main__':
    main()
