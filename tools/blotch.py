#!/usr/bin/env python3
"""Blotches: the error of a denoiser's output on flat regions at the scale
of the blotches issue 32 lists for the learned methods at 1 spp (10-20 px),
beside the PSNR that hides them (docs/quality.md, "Blotches on flat
walls").

    blotch.py SEQ_DIR LABEL=OUT_DIR [LABEL=OUT_DIR ...] [--frames 0,-1]
              [--region Y0,Y1,X0,X1]

For each frame asked for (negative: from the end) and each output, in the
display domain of `mcdenoise score` (clamp(x, 0, 1)^(1/2.2)) per channel:
  - the flat pixels: the reference luminance's standard deviation over the
    pixel's 7x7 window under 0.01 (walls, floors, sky), inside --region
    when given; their share is printed;
  - the error e = out - ref, band-passed as the difference of two box
    means (5x5 minus 17x17: the blotches' scale; 11x11 minus 41x41: the
    next octave, where a slow shading error sits);
  - each band's root mean square over the flat pixels and channels, x 1000.
Reads EXR with tools/exrio.py (numpy only).
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from exrio import read_exr  # noqa: E402

BANDS = ((2, 8), (5, 20))


def display(path):
    c = read_exr(path)
    return [np.clip(np.nan_to_num(c[k].astype(np.float64)), 0, 1) ** (1 / 2.2) for k in ('R', 'G', 'B')]


def box(a, r):
    """Mean over the (2r+1)^2 window, of the pixels inside the frame."""
    h, w = a.shape
    c = np.pad(np.cumsum(np.cumsum(a, 0), 1), ((1, 0), (1, 0)))
    ys, xs = np.arange(h), np.arange(w)
    y0, y1 = np.maximum(ys - r, 0), np.minimum(ys + r + 1, h)
    x0, x1 = np.maximum(xs - r, 0), np.minimum(xs + r + 1, w)
    s = c[y1][:, x1] - c[y0][:, x1] - c[y1][:, x0] + c[y0][:, x0]
    return s / ((y1 - y0)[:, None] * (x1 - x0)[None, :])


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('seq')
    p.add_argument('outputs', nargs='+', help='LABEL=DIR')
    p.add_argument('--frames', default='0,-1')
    p.add_argument('--region', help='Y0,Y1,X0,X1: only the flat pixels inside')
    a = p.parse_args()
    refdir = os.path.join(a.seq, 'ref')
    names = sorted(f for f in os.listdir(refdir) if f.endswith('.exr')) if os.path.isdir(refdir) else []
    if not names:
        sys.exit('blotch.py: no reference frames in %s' % refdir)
    outs = []
    for o in a.outputs:
        if '=' not in o:
            sys.exit('blotch.py: output %r is not LABEL=DIR' % o)
        outs.append(tuple(o.split('=', 1)))
    try:
        frames = [int(v) for v in a.frames.split(',')]
        region = [int(v) for v in a.region.split(',')] if a.region else None
    except ValueError:
        sys.exit('blotch.py: --frames and --region take integers separated by commas')
    if region is not None and len(region) != 4:
        sys.exit('blotch.py: --region takes Y0,Y1,X0,X1')
    for k in frames:
        if not -len(names) <= k < len(names):
            sys.exit('blotch.py: no frame %d (%d frames)' % (k, len(names)))
        name = names[k]
        ref = display(os.path.join(refdir, name))
        lum = 0.2126 * ref[0] + 0.7152 * ref[1] + 0.0722 * ref[2]
        flat = np.sqrt(np.maximum(box(lum * lum, 3) - box(lum, 3) ** 2, 0)) < 0.01
        if region is not None:
            inside = np.zeros_like(flat)
            inside[region[0]:region[1], region[2]:region[3]] = True
            flat &= inside
        print('%s %s: flat %.0f %% of the frame' % (os.path.basename(os.path.normpath(a.seq)), name, 100 * flat.mean()))
        if not flat.any():
            continue
        for label, d in outs:
            path = os.path.join(d, name)
            if not os.path.exists(path):
                sys.exit('blotch.py: %s has no %s' % (d, name))
            out = display(path)
            rms = []
            for r0, r1 in BANDS:
                s = 0.0
                for c in range(3):
                    e = out[c] - ref[c]
                    s += ((box(e, r0) - box(e, r1))[flat] ** 2).mean()
                rms.append(np.sqrt(s / 3) * 1000)
            print('  %-12s %s' % (label, '  '.join('%dx%d-%dx%d %5.2f' % (2 * r0 + 1, 2 * r0 + 1, 2 * r1 + 1, 2 * r1 + 1, v)
                                                   for (r0, r1), v in zip(BANDS, rms))))


if __name__ == '__main__':
    main()
