#!/usr/bin/env python3
"""The classical denoisers on the test corpus (tests/fixtures/corpus): the
tables of the README and docs/quality.md.

    tools/.venv/bin/python tools/corpus_table.py [-o OUT.md] [--no-plain]

Per scene, with the pair (A and B) and with one estimate (B.* dropped):
the input's PSNR, `atrous` and `sure-atrous` with their defaults, `atrous`
without the firefly clamp, an `atrous` --phi-color sweep, and, with one
estimate, the plain a-trous yardstick of tools/plain_atrous.py at its best
colour and position sigmas for that frame (tuned on the reference) and at
one setting for the whole corpus. PSNR as mcdenoise's (display values),
mean over a scene's frames; the yardstick on the scene's last frame, where
`atrous` is scored on the same frame. mcdenoise from target/release (or
$MCDENOISE).
"""
import argparse
import json
import os
import shutil
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
import plain_atrous as pa  # noqa: E402
from eval_learned import mcd, run  # noqa: E402
from exrio import read_exr, stack  # noqa: E402

C = os.path.join(ROOT, 'tests', 'fixtures', 'corpus')
SCENES = [('cornell 4 spp', 'cornell_4spp', 'cornell_ref'), ('cornell 16 spp', 'cornell_16spp', 'cornell_ref'),
          ('cornell 64 spp', 'cornell_64spp', 'cornell_ref'), ('box 4 spp', 'box_4spp', 'box_ref'),
          ('box 16 spp', 'box_16spp', 'box_ref'), ('box 64 spp', 'box_64spp', 'box_ref'),
          ('glossy (1 spp)', 'glossy', 'glossy/ref'), ('hdr (1 spp)', 'hdr', 'hdr/ref'), ('dim (1 spp)', 'dim', 'dim/ref')]
PHIS = [16, 64, 256, 1024, 2048, 8192]
PLAIN_SIGMA_C = [0.25, 1, 4, 8, 16, 64]
PLAIN_SIGMA_X = [0.01, 0.02, 0.05, 0.1]


def strip_b(src_dir, dst_dir, mean_dir):
    """Copies the frames of src_dir without their B.* channels into dst_dir,
    and the mean of the pair, (A + B) / 2, as R, G, B into mean_dir."""
    import OpenEXR
    os.makedirs(dst_dir, exist_ok=True)
    os.makedirs(mean_dir, exist_ok=True)
    for n in sorted(os.listdir(src_dir)):
        if not n.endswith('.exr'):
            continue
        with OpenEXR.File(os.path.join(src_dir, n), separate_channels=True) as f:
            ch = {k: np.asarray(v.pixels) for k, v in f.channels().items()}
        one = {k: v for k, v in ch.items() if not k.startswith('B.')}
        mean = {c: (0.5 * (ch[c].astype(np.float32) + ch['B.' + c].astype(np.float32))) for c in 'RGB'}
        hdr = {'compression': OpenEXR.ZIP_COMPRESSION, 'type': OpenEXR.scanlineimage}
        OpenEXR.File(hdr, one).write(os.path.join(dst_dir, n))
        OpenEXR.File(hdr, mean).write(os.path.join(mean_dir, n))


def denoise(inp, ref, tmp, args):
    out = os.path.join(tmp, 'out')
    shutil.rmtree(out, ignore_errors=True)
    run([mcd(), 'denoise', '--quiet', '--threads', '2'] + args + [inp, '-o', out])
    j = json.loads(run([mcd(), 'score', '--reference', ref, out, '--json']).splitlines()[-1])
    return j['mean']['psnr'], j['files'][-1]['psnr']


def input_psnr(inp, ref):
    j = json.loads(run([mcd(), 'score', '--reference', ref, inp, '--json']).splitlines()[-1])
    return j['mean']['psnr']


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('-o', '--output')
    ap.add_argument('--no-plain', action='store_true')
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, d, r in SCENES:
            src, ref = os.path.join(C, d), os.path.join(C, r)
            single, mean = os.path.join(tmp, 'single_' + d), os.path.join(tmp, 'mean_' + d)
            strip_b(src, single, mean)
            for mode, inp in (('A+B', src), ('one', single)):
                row = {'scene': name, 'mode': mode}
                # The input the methods see: the mean of the pair, or the one estimate.
                row['input'] = input_psnr(mean if mode == 'A+B' else inp, ref)
                row['atrous'], last = denoise(inp, ref, tmp, ['--method', 'atrous'])
                row['sure'] = denoise(inp, ref, tmp, ['--method', 'sure-atrous'])[0]
                row['noclamp'] = denoise(inp, ref, tmp, ['--method', 'atrous', '--firefly-clamp', '0'])[0]
                row['phi'] = {p: denoise(inp, ref, tmp, ['--method', 'atrous', '--phi-color', str(p)])[0] for p in PHIS}
                if mode == 'one' and not a.no_plain:
                    frames = sorted(n for n in os.listdir(src) if n.endswith('.exr'))
                    ch = read_exr(os.path.join(single, frames[-1]))
                    rf = stack(read_exr(os.path.join(ref, frames[-1])), ['R', 'G', 'B'])
                    y = np.nan_to_num(stack(ch, ['R', 'G', 'B']))
                    al = stack(ch, ['albedo.R', 'albedo.G', 'albedo.B'])
                    n = stack(ch, ['normal.X', 'normal.Y', 'normal.Z'])
                    x = stack(ch, ['position.X', 'position.Y', 'position.Z'])
                    q = al + pa.EPS
                    ext = max(np.ptp(x.reshape(-1, 3), axis=0).max(), 1e-6)
                    grid = {(sc, sx): pa.psnr(pa.atrous(y / q, n, x, sc, sigma_x=sx * ext) * q, rf)
                            for sc in PLAIN_SIGMA_C for sx in PLAIN_SIGMA_X}
                    row['plain_grid'] = {'%g/%g' % k: v for k, v in grid.items()}
                    row['plain_best'] = max(grid.items(), key=lambda kv: kv[1])
                    row['atrous_last'] = last
                rows.append(row)
                print(json.dumps(row, default=str), flush=True)
    # One plain setting for the whole corpus: the best mean over the scenes.
    ones = [r for r in rows if 'plain_grid' in r]
    fixed = None
    if ones:
        keys = list(ones[0]['plain_grid'])
        fixed = max(keys, key=lambda k: np.mean([r['plain_grid'][k] for r in ones]))
    lines = ['| scene | noise | input | atrous | sure-atrous | atrous, no clamp |'
             + ''.join(' phi %d |' % p for p in PHIS), '|---|---|---|---|---|---|' + '---|' * len(PHIS)]
    for r in rows:
        lines.append('| %s | %s | %.2f | **%.2f** | %.2f | %.2f |' % (
            r['scene'], r['mode'], r['input'], r['atrous'], r['sure'], r['noclamp'])
            + ''.join(' %.2f |' % r['phi'][p] for p in PHIS))
    if ones:
        lines += ['', 'One estimate, last frame of each scene: `atrous` (defaults) against plain a-trous '
                  '(tools/plain_atrous.py) tuned on the reference per frame, and at the one setting best '
                  'over the corpus (sigma_c / sigma_x = %s).' % fixed, '',
                  '| scene | atrous | plain, tuned per frame (sigma_c / sigma_x) | plain, one setting |', '|---|---|---|---|']
        for r in ones:
            (sc, sx), best = r['plain_best']
            lines.append('| %s | %.2f | %.2f (%g / %g) | %.2f |' % (
                r['scene'], r['atrous_last'], best, sc, sx, r['plain_grid'][fixed]))
    text = '\n'.join(lines) + '\n'
    print(text)
    if a.output:
        with open(a.output, 'w') as f:
            f.write(text)


if __name__ == '__main__':
    main()
