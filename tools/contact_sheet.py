#!/usr/bin/env python3
"""A contact sheet PNG of one frame as several methods denoised it: the
frames given, tone-mapped alike (tools/preview.py's curve), in rows of
COLS tiles, optionally each tile scaled up by SCALE (nearest neighbour).

    tools/.venv/bin/python tools/contact_sheet.py out.png a.exr b.exr ... [--cols 4] [--scale 2] \
        [--crop Y0,Y1,X0,X1] [--contrast K]

--crop keeps rows Y0..Y1 and columns X0..X1 of every frame; --contrast K
spreads each channel's tone-mapped values K times about the first tile's
mean (to show low-frequency error on a flat wall).

tools/eval_learned.py --sheets writes one per sequence (its last frame:
input, TA, the learned methods, OIDN high, reference; the order is in the
file name list it prints).
"""

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from exrio import read_exr, stack  # noqa: E402
from preview import tonemap, write_png  # noqa: E402


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('out')
    p.add_argument('frames', nargs='+')
    p.add_argument('--cols', type=int, default=4)
    p.add_argument('--scale', type=int, default=1)
    p.add_argument('--crop', default=None, help='Y0,Y1,X0,X1')
    p.add_argument('--contrast', type=float, default=1.0)
    a = p.parse_args()
    tiles = []
    centre = None
    for f in a.frames:
        t = tonemap(stack(read_exr(f), ['R', 'G', 'B']))
        if a.crop:
            y0, y1, x0, x1 = (int(v) for v in a.crop.split(','))
            t = t[y0:y1, x0:x1]
        if a.contrast != 1.0:
            if centre is None:
                centre = t.reshape(-1, 3).mean(0)
            t = np.clip((t - centre) * a.contrast + 0.5, 0, 1)
        tiles.append(np.repeat(np.repeat(t, a.scale, 0), a.scale, 1))
    h = max(t.shape[0] for t in tiles)
    w = max(t.shape[1] for t in tiles)
    tiles = [np.pad(t, ((0, h - t.shape[0]), (0, w - t.shape[1]), (0, 0))) for t in tiles]
    while len(tiles) % a.cols:
        tiles.append(np.zeros((h, w, 3)))
    rows = [np.concatenate(tiles[i:i + a.cols], axis=1) for i in range(0, len(tiles), a.cols)]
    sheet = np.concatenate(rows, axis=0)
    write_png(a.out, (np.clip(sheet, 0, 1) * 255 + 0.5).astype(np.uint8))


if __name__ == '__main__':
    sys.exit(main())
