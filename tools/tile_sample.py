#!/usr/bin/env python3
"""Tiles the bundled sample (samples/, 160x96) to a larger frame size, for
the time-per-frame measurements of docs/quality.md (every channel, f32).

    tools/.venv/bin/python tools/tile_sample.py OUT_DIR [--size 1280x720] [--frames 8]

The motion vectors are tiled too, so temporal accumulation reprojects as
on the sample; the pictures repeat, which does not change the work done.
"""
import argparse
import os

import numpy as np
import OpenEXR

HERE = os.path.dirname(os.path.abspath(__file__))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('out')
    ap.add_argument('--size', default='1280x720')
    ap.add_argument('--frames', type=int, default=8)
    a = ap.parse_args()
    w, h = (int(v) for v in a.size.split('x'))
    src = os.path.join(HERE, '..', 'samples')
    names = sorted(n for n in os.listdir(src) if n.startswith('frame_') and n.endswith('.exr'))[:a.frames]
    os.makedirs(a.out, exist_ok=True)
    for n in names:
        with OpenEXR.File(os.path.join(src, n), separate_channels=True) as f:
            ch = {k: np.asarray(c.pixels, dtype=np.float32) for k, c in f.channels().items()}
        reps = lambda v: (-(-h // v.shape[0]), -(-w // v.shape[1]))  # noqa: E731
        out = {k: np.ascontiguousarray(np.tile(v, reps(v))[:h, :w]) for k, v in ch.items()}
        OpenEXR.File({'compression': OpenEXR.ZIP_COMPRESSION, 'type': OpenEXR.scanlineimage}, out).write(
            os.path.join(a.out, n))
    print('wrote %d frames of %dx%d to %s' % (len(names), w, h, a.out))


if __name__ == '__main__':
    main()
