#!/usr/bin/env python3
"""The blotch band's error split into noise and bias, near edges and inside
flat regions, over independent renders of the same frames.

    blotch_split.py REF_SEQ OUT LABEL [LABEL ...] [--frames 0,-1] [--edge 8]

REF_SEQ is a rendered sequence whose ref/ frames are the references (e.g.
/work/data/foreign/lounge_pan; the realisations may hold some of its frames,
rendered with render.py --frame-range, and --frames indexes theirs); OUT holds the denoised realisations,
OUT/LABEL_K/frame_NNNN.exr for K = 1..N (N: as many as exist for the
first label), each the same frames rendered with another seed and
denoised (tools/blotch-split.sh makes them). The error is taken as
tools/blotch.py takes it: display domain, the 5x5-minus-17x17 band, over
the flat pixels (the reference luminance's 7x7 standard deviation under
0.01), x 1000. For each frame and label:

  - total: the band's root mean square over the realisations (what
    blotch.py prints for one of them);
  - noise: the band of each realisation's difference from the
    realisations' mean (their spread; what looks like blotches);
  - bias: the band of the mean's difference from the reference, with the
    mean's own share of the noise taken out (total^2 ~ noise^2 + bias^2:
    what every realisation has in common, the same picture whatever the
    seed; the reference's own noise counts here, small at 1024 spp);

(the squares are unbiased estimates over independent realisations; their
square roots, printed, are a little low, and a bias under the noise's share
is printed as 0);

each over all flat pixels, the flat pixels within --edge pixels of an edge
of the frame's normal or albedo (a normal difference over 0.1 or an albedo
difference over 0.05 to a neighbour, in the G-buffer of REF_SEQ's frame;
each realisation's own differs from it only by its AOVs' sampling noise),
and the flat pixels farther inside.
--picture writes the first frame's reference and each label's bias (what
the realisations share), to look at where it is. Reads EXR with
tools/exrio.py (numpy only).
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from blotch import box, display  # noqa: E402
from exrio import read_exr  # noqa: E402

R0, R1 = 2, 8


def band(e):
    return box(e, R0) - box(e, R1)


def edges(planes, limit):
    """Pixels whose value differs from a right or lower neighbour's by more
    than `limit` (Euclidean over the planes), both pixels of the pair."""
    e = np.zeros(planes.shape[1:], bool)
    d = np.sqrt(((planes[:, 1:, :] - planes[:, :-1, :]) ** 2).sum(0)) > limit
    e[1:, :] |= d
    e[:-1, :] |= d
    d = np.sqrt(((planes[:, :, 1:] - planes[:, :, :-1]) ** 2).sum(0)) > limit
    e[:, 1:] |= d
    e[:, :-1] |= d
    return e


def split(outs, ref, mask):
    """(total, noise, bias) x 1000 of the realisations `outs` (N x 3 x H x W)
    against `ref` over `mask`."""
    n = len(outs)
    mean = outs.mean(0)
    ms = lambda e: np.mean(np.stack([band(e[c])[mask] for c in range(3)]) ** 2)  # noqa: E731
    total = np.mean([ms(o - ref) for o in outs])
    noise = np.mean([ms(o - mean) for o in outs]) * n / (n - 1)
    bias = max(ms(mean - ref) - noise / n, 0.0)
    return [1000 * np.sqrt(v) for v in (total, noise, bias)]


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('ref_seq')
    p.add_argument('out')
    p.add_argument('labels', nargs='+')
    p.add_argument('--frames', default='0,-1')
    p.add_argument('--edge', type=int, default=8, help='distance from an edge that counts as near, pixels')
    p.add_argument('--picture', help='PNG: for the first frame asked for, the reference and each label\'s bias '
                   '(the realisations\' mean minus the reference, grey, x --gain around mid-grey), stacked')
    p.add_argument('--gain', type=float, default=8.0)
    a = p.parse_args()
    refdir = os.path.join(a.ref_seq, 'ref')
    count = 0
    while os.path.isdir(os.path.join(a.out, '%s_%d' % (a.labels[0], count + 1))):
        count += 1
    if count < 2:
        sys.exit('blotch_split.py: need at least 2 realisations %s/%s_1, _2, ...' % (a.out, a.labels[0]))
    # The frames the realisations have (they may be the sequence's first few).
    first = os.path.join(a.out, '%s_1' % a.labels[0])
    names = sorted(f for f in os.listdir(first) if f.endswith('.exr'))
    if not names:
        sys.exit('blotch_split.py: no frames in %s' % first)
    for name in names:
        if not os.path.exists(os.path.join(refdir, name)):
            sys.exit('blotch_split.py: no reference %s' % os.path.join(refdir, name))
    try:
        asked = [int(v) for v in a.frames.split(',')]
    except ValueError:
        sys.exit('blotch_split.py: --frames takes integers separated by commas')
    for v in asked:
        if not -len(names) <= v < len(names):
            sys.exit('blotch_split.py: no frame %d (the realisations have %d)' % (v, len(names)))
    frames = sorted({v % len(names) for v in asked})
    for k in frames:
        name = names[k]
        ref = np.stack(display(os.path.join(refdir, name)))
        lum = 0.2126 * ref[0] + 0.7152 * ref[1] + 0.0722 * ref[2]
        flat = np.sqrt(np.maximum(box(lum * lum, 3) - box(lum, 3) ** 2, 0)) < 0.01
        g = read_exr(os.path.join(a.ref_seq, name))
        try:
            nrm = np.stack([np.nan_to_num(g['normal.' + c].astype(np.float64)) for c in 'XYZ'])
            alb = np.stack([np.nan_to_num(g['albedo.' + c].astype(np.float64)) for c in 'RGB'])
        except KeyError as e:
            sys.exit('blotch_split.py: %s has no %s channel' % (os.path.join(a.ref_seq, name), e))
        near = box((edges(nrm, 0.1) | edges(alb, 0.05)).astype(np.float64), a.edge) > 0
        masks = (('all', flat), ('near edges', flat & near), ('inside', flat & ~near))
        print('%s %s: %d realisations; flat %.0f %% of the frame, %.0f %% of it within %d px of an edge'
              % (os.path.basename(os.path.normpath(a.ref_seq)), name, count, 100 * flat.mean(),
                 100 * (flat & near).sum() / max(flat.sum(), 1), a.edge))
        print('  %-12s %s' % ('', '  '.join('%-24s' % m for m, _ in masks)))
        print('  %-12s %s' % ('', '  '.join('%-24s' % 'total noise  bias' for _ in masks)))
        rows = [np.moveaxis(ref, 0, -1)]
        for label in a.labels:
            paths = [os.path.join(a.out, '%s_%d' % (label, i), name) for i in range(1, count + 1)]
            missing = [q for q in paths if not os.path.exists(q)]
            if missing:
                sys.exit('blotch_split.py: missing %s' % missing[0])
            outs = np.stack([np.stack(display(q)) for q in paths])
            cells = []
            for _, m in masks:
                cells.append('%5.2f %5.2f %5.2f' % tuple(split(outs, ref, m)) if m.any() else '   -     -     - ')
            print('  %-12s %s' % (label, '  '.join('%-24s' % c for c in cells)))
            e = (outs.mean(0) - ref).mean(0)
            rows.append(np.repeat(np.clip(0.5 + a.gain * e, 0, 1)[..., None], 3, -1))
        if a.picture and k == frames[0]:
            from preview import write_png
            img = (np.concatenate(rows, 0) * 255 + 0.5).astype(np.uint8)
            write_png(a.picture, img)
            print('  wrote %s (the reference, then the bias of %s, x %g)' % (a.picture, ', '.join(a.labels), a.gain))


if __name__ == '__main__':
    main()
