#!/usr/bin/env python3
"""A plain edge-avoiding a-trous filter (Dammertz et al. 2010), the yardstick
for mcdenoise's single-estimate `atrous`.

Independent of the Rust code: numpy only, on one image (`R,G,B`; `B.*` is
ignored), with albedo demodulation, normal and position edge stops, and one
fixed colour sigma halved at each of the 5 levels (hole spacings 1..16). Its
colour sigma is tuned per frame against the reference (the best of a sweep),
so it is the best this filter can do, not what a user without a reference
gets.

    tools/.venv/bin/python tools/plain_atrous.py FRAME.exr REF.exr [--sigmas S,S,...] [--json]

Prints the input's PSNR and the filtered PSNR per colour sigma (PSNR as
mcdenoise's: clamp to [0, 1], gamma 1/2.2, over the three channels), then
the best.
"""
import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from exrio import read_exr, stack  # noqa: E402

B3 = np.array([1 / 16, 1 / 4, 3 / 8, 1 / 4, 1 / 16])
EPS = 1e-3


def psnr(x, r):
    d = lambda v: np.clip(np.nan_to_num(v), 0, 1) ** (1 / 2.2)  # noqa: E731
    mse = np.mean((d(x) - d(r)) ** 2)
    return 10 * np.log10(1 / mse) if mse > 0 else float('inf')


def shifted(img, dy, dx):
    """img moved so that out[y, x] = img[y + dy, x + dx], and the mask of
    in-image taps (outside ones are left out, as mcdenoise does)."""
    h, w = img.shape[:2]
    out = np.zeros_like(img)
    mask = np.zeros((h, w), dtype=bool)
    ys, ye = max(0, -dy), min(h, h - dy)
    xs, xe = max(0, -dx), min(w, w - dx)
    if ys < ye and xs < xe:
        out[ys:ye, xs:xe] = img[ys + dy:ye + dy, xs + dx:xe + dx]
        mask[ys:ye, xs:xe] = True
    return out, mask


def atrous(c, normal, position, sigma_c, sigma_n=0.3, sigma_x=None, levels=5):
    """The filtered (H,W,3) image. sigma_c: colour sigma of level 0 (on the
    demodulated image), halved per level; sigma_x defaults to 1 % of the
    scene's extent."""
    if sigma_x is None:
        ext = np.ptp(position.reshape(-1, 3), axis=0).max() if position is not None else 1.0
        sigma_x = 0.01 * max(ext, 1e-6)
    for i in range(levels):
        step = 1 << i
        sc2 = (sigma_c * 2.0 ** -i) ** 2
        acc = np.zeros_like(c)
        wsum = np.zeros(c.shape[:2])
        for ky in range(5):
            for kx in range(5):
                dy, dx = (ky - 2) * step, (kx - 2) * step
                cq, m = shifted(c, dy, dx)
                wgt = B3[ky] * B3[kx] * m * np.exp(-np.sum((c - cq) ** 2, axis=-1) / sc2)
                if normal is not None:
                    nq, _ = shifted(normal, dy, dx)
                    wgt = wgt * np.exp(-np.sum((normal - nq) ** 2, axis=-1) / sigma_n ** 2)
                if position is not None:
                    xq, _ = shifted(position, dy, dx)
                    wgt = wgt * np.exp(-np.sum((position - xq) ** 2, axis=-1) / sigma_x ** 2)
                acc += wgt[..., None] * cq
                wsum += wgt
        c = acc / wsum[..., None]
    return c


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('frame')
    ap.add_argument('ref')
    ap.add_argument('--sigmas', default='0.05,0.1,0.2,0.3,0.5,0.75,1,1.5,2,3,5,8')
    ap.add_argument('--sigma-x', default='0.01,0.05,0.2',
                    help='position sigmas to sweep, as fractions of the scene extent')
    ap.add_argument('--json', action='store_true')
    a = ap.parse_args()
    ch = read_exr(a.frame)
    ref = stack(read_exr(a.ref), ['R', 'G', 'B'])
    y = np.nan_to_num(stack(ch, ['R', 'G', 'B']))
    albedo = stack(ch, ['albedo.R', 'albedo.G', 'albedo.B']) if 'albedo.R' in ch else None
    normal = stack(ch, ['normal.X', 'normal.Y', 'normal.Z']) if 'normal.X' in ch else None
    position = stack(ch, ['position.X', 'position.Y', 'position.Z']) if 'position.X' in ch else None
    c = y / (albedo + EPS) if albedo is not None else y
    ext = np.ptp(position.reshape(-1, 3), axis=0).max() if position is not None else 1.0
    rows = []
    for fx in [float(v) for v in a.sigma_x.split(',')]:
        for s in [float(v) for v in a.sigmas.split(',')]:
            out = atrous(c, normal, position, s, sigma_x=fx * max(ext, 1e-6))
            if albedo is not None:
                out = out * (albedo + EPS)
            rows.append((s, fx, psnr(out, ref)))
    best = max(rows, key=lambda r: r[2])
    res = {'input_psnr': psnr(y, ref), 'sweep': rows, 'best_sigma_c': best[0], 'best_sigma_x': best[1],
           'best_psnr': best[2]}
    if a.json:
        print(json.dumps(res))
    else:
        print('input %.2f dB' % res['input_psnr'])
        for s, fx, p in rows:
            print('sigma_c %-6g sigma_x %-5g %.2f dB' % (s, fx, p))
        print('best sigma_c %g sigma_x %g: %.2f dB (+%.2f)' % (best[0], best[1], best[2], best[2] - res['input_psnr']))


if __name__ == '__main__':
    main()
