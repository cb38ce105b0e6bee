#!/usr/bin/env python3
"""Intel Open Image Denoise (the `pyoidn` package) on rendered frames: the
CPU denoiser a renderer engineer would otherwise pick, run on the same
frames as mcdenoise and scored with `mcdenoise score`.

    python tools/oidn_denoise.py IN_DIR -o OUT_DIR [--quality fast|balanced|high] [--mean-ab]
    python tools/oidn_denoise.py --time 1280x720 [--quality high]

Inputs: colour (R,G,B; with --mean-ab the mean of R,G,B and B.R,B.G,B.B),
albedo clamped to [0, 1] (OIDN expects a reflectance in that range; our
renders' albedo can exceed 1 on some surfaces), normal. HDR mode. OIDN
uses every core of the machine (it has no thread setting in this API):
on the 2-core machine that is 2 threads. --time tiles a frame up to the
size and reports the median of 10 runs after 3 warm-ups.
"""
import argparse
import os
import subprocess
import sys
import time

import numpy as np
import pyoidn

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import exrio  # noqa: E402


def hwc(d, names):
    return np.ascontiguousarray(np.stack([d[n] for n in names], -1).astype(np.float32))


def frame_images(path, mean_ab):
    d = exrio.read_exr(path)
    color = hwc(d, ['R', 'G', 'B'])
    if mean_ab and 'B.R' in d:
        color = 0.5 * (color + hwc(d, ['B.R', 'B.G', 'B.B']))
    albedo = np.clip(hwc(d, ['albedo.R', 'albedo.G', 'albedo.B']), 0, 1) if 'albedo.R' in d else None
    normal = hwc(d, ['normal.X', 'normal.Y', 'normal.Z']) if 'normal.X' in d else None
    return color, albedo, normal


def run(color, albedo, normal, quality):
    return pyoidn.denoise(color, albedo=albedo, normal=normal, hdr=True, quality=quality)


def write_rgb(path, img):
    import OpenEXR
    ch = {c: np.ascontiguousarray(img[..., i]).astype(np.float32) for i, c in enumerate('RGB')}
    with OpenEXR.File({'compression': OpenEXR.ZIP_COMPRESSION, 'type': OpenEXR.scanlineimage}, ch) as f:
        f.write(path)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('input', nargs='?')
    p.add_argument('-o', '--output')
    p.add_argument('--quality', default='high', choices=['fast', 'balanced', 'high'])
    p.add_argument('--mean-ab', action='store_true', help='denoise the mean of the two estimates')
    p.add_argument('--time', help='WxH: time one frame of this size')
    p.add_argument('--frame', help='the frame to tile for --time (default: the bundled sample)')
    a = p.parse_args()
    if a.time:
        w, h = (int(v) for v in a.time.split('x'))
        src = a.frame or os.path.join(HERE, '..', 'samples', 'frame_0000.exr')
        c, al, n = frame_images(src, a.mean_ab)
        tile = lambda im: None if im is None else np.ascontiguousarray(np.tile(im, (h // im.shape[0] + 1, w // im.shape[1] + 1, 1))[:h, :w])
        c, al, n = tile(c), tile(al), tile(n)
        for _ in range(3):
            run(c, al, n, a.quality)
        ts = []
        for _ in range(10):
            t0 = time.perf_counter()
            run(c, al, n, a.quality)
            ts.append((time.perf_counter() - t0) * 1e3)
        ts.sort()
        cpu = subprocess.run(['lscpu'], capture_output=True, text=True).stdout
        model = next((l.split(':', 1)[1].strip() for l in cpu.splitlines() if l.startswith('Model name')), '?')
        print('OIDN %s quality %s, %dx%d on %s (%d cores): median %.1f ms, fastest %.1f ms'
              % (pyoidn.__version__ if hasattr(pyoidn, '__version__') else '', a.quality, w, h, model, os.cpu_count(), ts[5], ts[0]))
        return
    if not a.input or not a.output:
        p.error('IN_DIR and -o OUT_DIR are needed (or --time)')
    os.makedirs(a.output, exist_ok=True)
    names = sorted(f for f in os.listdir(a.input) if f.endswith('.exr'))
    t_total = 0.0
    for n in names:
        c, al, nm = frame_images(os.path.join(a.input, n), a.mean_ab)
        t0 = time.perf_counter()
        out = run(c, al, nm, a.quality)
        t_total += time.perf_counter() - t0
        write_rgb(os.path.join(a.output, n), np.asarray(out))
    print('OIDN (%s) denoised %d frames into %s: %.1f ms/frame' % (a.quality, len(names), a.output, 1e3 * t_total / max(len(names), 1)))


if __name__ == '__main__':
    main()
