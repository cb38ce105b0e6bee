#!/usr/bin/env python3
"""The cross-regression figures of docs/cross.md: per-frame relMSE, PSNR and
flicker of `--method cross` against (A+B)/2, `sure-atrous`, WSKP-6 and Intel
Open Image Denoise (fed (A+B)/2) on held-out rendered sequences.

    tools/.venv-peers/bin/python tools/cross_figures.py SEQ_DIR... -o OUT_DIR [--threads 2]

For each sequence: (A+B)/2 written as EXR, every method run with
`target/release/mcdenoise denoise`, OIDN with tools/oidn_denoise.py
(skipped with a note when pyoidn is missing), everything scored per frame
with `mcdenoise score --json` against SEQ_DIR/ref. Writes OUT_DIR/cross.csv
(sequence, method, frame, relmse, psnr, flicker), OUT_DIR/summary.csv
(first/last-4-frame means) and OUT_DIR/cross_<seq>.svg (relMSE per frame,
log scale).
"""
import argparse
import json
import math
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
BIN = os.path.join(ROOT, 'target', 'release', 'mcdenoise')

METHODS = [
    ('mean', '(A+B)/2'),
    ('sure-atrous', 'sure-atrous'),
    ('wskp', 'WSKP-6'),
    ('oidn', 'OIDN (A+B)/2'),
    ('cross', 'cross'),
]
COLORS = {'mean': '#888888', 'sure-atrous': '#1f77b4', 'wskp': '#2ca02c', 'oidn': '#9467bd', 'cross': '#d62728'}


def run(cmd):
    print('+', ' '.join(cmd), flush=True)
    return subprocess.run(cmd, check=True, capture_output=True, text=True)


def write_mean(seq, out):
    import numpy as np
    import exrio
    import oidn_denoise
    os.makedirs(out, exist_ok=True)
    for p in exrio.frame_paths(seq):
        ch = exrio.read_exr(p)
        a = exrio.stack(ch, ['R', 'G', 'B'])
        b = exrio.stack(ch, ['B.R', 'B.G', 'B.B'])
        oidn_denoise.write_rgb(os.path.join(out, os.path.basename(p)), (0.5 * (a + b)).astype(np.float32))


def score(ref, out):
    r = run([BIN, 'score', '--reference', ref, out, '--json'])
    return json.loads(r.stdout)['files']


def svg(path, title, series, frames):
    """relMSE per frame, log y axis."""
    W, H, L, R, T, B = 640, 360, 60, 150, 30, 40
    vals = [v for _, _, ys in series for v in ys if v > 0]
    lo, hi = math.floor(math.log10(min(vals))), math.ceil(math.log10(max(vals)))
    if hi == lo:
        hi = lo + 1
    X = lambda i: L + (W - L - R) * i / max(1, frames - 1)  # noqa: E731
    Y = lambda v: T + (H - T - B) * (hi - math.log10(max(v, 10.0 ** lo))) / (hi - lo)  # noqa: E731
    s = ['<svg xmlns="http://www.w3.org/2000/svg" width="%d" height="%d" font-family="sans-serif" font-size="11">' % (W, H),
         '<rect width="100%" height="100%" fill="white"/>',
         '<text x="%d" y="18" font-size="13">%s</text>' % (L, title)]
    for e in range(lo, hi + 1):
        y = Y(10.0 ** e)
        s.append('<line x1="%d" x2="%d" y1="%.1f" y2="%.1f" stroke="#ddd"/>' % (L, W - R, y, y))
        s.append('<text x="%d" y="%.1f" text-anchor="end">1e%d</text>' % (L - 4, y + 4, e))
    for i in range(0, frames, max(1, frames // 8)):
        s.append('<text x="%.1f" y="%d" text-anchor="middle">%d</text>' % (X(i), H - B + 15, i))
    s.append('<text x="%d" y="%d" text-anchor="middle">frame</text>' % ((L + W - R) // 2, H - 5))
    s.append('<text x="12" y="%d" transform="rotate(-90 12 %d)" text-anchor="middle">relMSE</text>' % (H // 2, H // 2))
    for k, (key, label, ys) in enumerate(series):
        pts = ' '.join('%.1f,%.1f' % (X(i), Y(v)) for i, v in enumerate(ys))
        s.append('<polyline fill="none" stroke="%s" stroke-width="2" points="%s"/>' % (COLORS[key], pts))
        s.append('<text x="%d" y="%d" fill="%s">%s</text>' % (W - R + 8, T + 16 * k + 10, COLORS[key], label))
    s.append('</svg>')
    with open(path, 'w') as f:
        f.write('\n'.join(s))


def main():
    p = argparse.ArgumentParser()
    p.add_argument('seqs', nargs='+')
    p.add_argument('-o', '--out', required=True)
    p.add_argument('--threads', default='2')
    a = p.parse_args()
    os.makedirs(a.out, exist_ok=True)
    rows, summary, notes = [], [], []
    for seq in a.seqs:
        name = os.path.basename(os.path.normpath(seq))
        ref = os.path.join(seq, 'ref')
        series = []
        for key, label in METHODS:
            out = os.path.join(a.out, name, key)
            try:
                if key == 'mean':
                    write_mean(seq, out)
                elif key == 'oidn':
                    run([sys.executable, os.path.join(HERE, 'oidn_denoise.py'), seq, '-o', out,
                         '--color', 'ab-mean', '--threads', a.threads])
                else:
                    cmd = [BIN, 'denoise', '--method', key, '--threads', a.threads, '--timings', seq, '-o', out]
                    if key == 'wskp':
                        cmd += ['--weights', os.path.join(ROOT, 'std-host/weights/wskp6.safetensors'), '--layers', '6']
                    r = run(cmd)
                    with open(os.path.join(a.out, name, key + '.log'), 'w') as f:
                        f.write(r.stdout + r.stderr)
            except (subprocess.CalledProcessError, ImportError) as e:
                notes.append('%s %s skipped: %s' % (name, key, getattr(e, 'stderr', None) or e))
                print(notes[-1])
                continue
            files = score(ref, out)
            ys = [f['relmse'] for f in files]
            for i, f in enumerate(files):
                rows.append((name, key, i, f['relmse'], f['psnr'], f['flicker']))
            series.append((key, label, ys))
            first = sum(ys[:4]) / min(4, len(ys))
            last = sum(ys[-4:]) / min(4, len(ys))
            fl = [f['flicker'] for f in files if f['flicker'] is not None]
            psnr = sum(f['psnr'] for f in files[-4:]) / min(4, len(files))
            summary.append((name, key, first, last, psnr, math.sqrt(sum(v * v for v in fl) / len(fl)) if fl else float('nan')))
        svg(os.path.join(a.out, 'cross_%s.svg' % name), '%s: relMSE per frame (1+1 spp)' % name, series,
            max(len(s[2]) for s in series))
    with open(os.path.join(a.out, 'cross.csv'), 'w') as f:
        f.write('sequence,method,frame,relmse,psnr,flicker\n')
        for r in rows:
            f.write('%s,%s,%d,%.6g,%.4f,%s\n' % (r[0], r[1], r[2], r[3], r[4], '' if r[5] is None else '%.6g' % r[5]))
    with open(os.path.join(a.out, 'summary.csv'), 'w') as f:
        f.write('sequence,method,relmse_first4,relmse_last4,psnr_last4,flicker\n')
        for r in summary:
            f.write('%s,%s,%.6g,%.6g,%.3f,%.6g\n' % r)
    for r in summary:
        print('%-16s %-12s relMSE first4 %.5f last4 %.5f  PSNR last4 %.2f  flicker %.5f' % r)
    for n in notes:
        print(n)


if __name__ == '__main__':
    main()
