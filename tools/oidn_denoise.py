#!/usr/bin/env python3
"""Intel Open Image Denoise (the `pyoidn` package, OIDN 2.5) on rendered frames:
the CPU denoiser users would otherwise pick, run on the same frames as
mcdenoise and scored with `mcdenoise score`.

    oidn_denoise.py IN_DIR -o OUT_DIR [--quality high] [--threads N] [--no-aux]
    oidn_denoise.py --time 1280x720 [--threads 2] [--quality high] [--frame F.exr]

Each frame is filtered on its own (OIDN is not temporal): the RT filter in
HDR mode on the 1-spp colour R,G,B (--color ab-mean: the mean of the two
1-spp estimates R,G,B and B.R,B.G,B.B), with the albedo (albedo.R/G/B,
clamped to [0, 1]: OIDN expects a reflectance in that range, and our albedo
may leave it slightly) and the world-space normal (normal.X/Y/Z, in [-1, 1])
as auxiliary images. Outputs: EXR R,G,B f32.

pyoidn exposes OIDN's device and filter parameters: --threads sets the CPU
device's `numThreads` (0 = OIDN's default, one per core), --quality sets the
filter's `quality` (fast, balanced, high, or default = high on CPUs), and
--clean-aux sets `cleanAux` (off by default: OIDN then prefilters albedo and
normal itself, as it must for auxiliary images that are not noise-free).

--time tiles a frame (default: samples/frame_0000.exr) up to WxH and reports
the median of --reps (>= 10) executions after 3 warm-ups, with the device and
filter committed once beforehand (as a renderer would).
"""
import argparse
import importlib.metadata
import os
import statistics
import subprocess
import sys
import time

import numpy as np
import pyoidn
from pyoidn.capi import oidn_Capi, oidn_ffi

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import exrio  # noqa: E402

QUALITIES = {'default': pyoidn.OIDN_QUALITY_DEFAULT, 'fast': pyoidn.OIDN_QUALITY_FAST,
             'balanced': pyoidn.OIDN_QUALITY_BALANCED, 'high': pyoidn.OIDN_QUALITY_HIGH}


def check(device, what):
    msg = oidn_ffi.new('const char**')
    code = int(oidn_Capi.oidnGetDeviceError(device._device, msg))
    if code != 0:
        text = oidn_ffi.string(msg[0]).decode(errors='replace') if msg[0] != oidn_ffi.NULL else ''
        raise SystemExit('OIDN: %s failed (error %d): %s' % (what, code, text))


class Denoiser:
    """One CPU device and one RT filter bound to fixed host images of one size;
    load() copies a frame in, run() executes, the result is in self.output."""

    def __init__(self, h, w, threads, quality, aux, clean_aux):
        self.device = pyoidn.Device(pyoidn.OIDN_DEVICE_TYPE_CPU)
        check(self.device, 'device creation')
        if threads:
            self.device.set_int('numThreads', threads)
        self.device.commit()
        check(self.device, 'device commit')
        self.threads = self.device.get_int('numThreads')
        self.color = np.zeros((h, w, 3), np.float32)
        self.albedo = np.zeros((h, w, 3), np.float32) if aux else None
        self.normal = np.zeros((h, w, 3), np.float32) if aux else None
        self.output = np.zeros((h, w, 3), np.float32)
        self.filter = pyoidn.Filter(self.device, pyoidn.OIDN_FILTER_TYPE_RT)
        f3 = pyoidn.OIDN_FORMAT_FLOAT3
        self.filter.set_image(pyoidn.OIDN_IMAGE_COLOR, self.color, f3)
        if aux:
            self.filter.set_image(pyoidn.OIDN_IMAGE_ALBEDO, self.albedo, f3)
            self.filter.set_image(pyoidn.OIDN_IMAGE_NORMAL, self.normal, f3)
        self.filter.set_image(pyoidn.OIDN_IMAGE_OUTPUT, self.output, f3)
        self.filter.set_bool('hdr', True)
        self.filter.set_bool('cleanAux', clean_aux)
        self.filter.set_quality(QUALITIES[quality])
        self.filter.commit()
        check(self.device, 'filter commit')

    def load(self, color, albedo, normal):
        self.color[...] = color
        if self.albedo is not None:
            self.albedo[...] = np.clip(albedo, 0.0, 1.0)
            self.normal[...] = normal

    def run(self):
        self.filter.execute()
        check(self.device, 'filter execution')
        return self.output

    def close(self):
        self.filter.release()
        self.device.release()


def hwc(ch, names):
    return np.stack([ch[n] for n in names], axis=-1).astype(np.float32)


def frame_images(path, color_mode):
    ch = exrio.read_exr(path)
    color = hwc(ch, ['R', 'G', 'B'])
    if color_mode == 'ab-mean':
        color = 0.5 * (color + hwc(ch, ['B.R', 'B.G', 'B.B']))
    albedo = hwc(ch, ['albedo.R', 'albedo.G', 'albedo.B'])
    normal = hwc(ch, ['normal.X', 'normal.Y', 'normal.Z'])
    return color, albedo, normal


def write_rgb(path, img):
    import OpenEXR
    chans = {c: np.ascontiguousarray(img[..., i], dtype=np.float32) for i, c in enumerate('RGB')}
    with OpenEXR.File({'compression': OpenEXR.ZIP_COMPRESSION, 'type': OpenEXR.scanlineimage}, chans) as f:
        f.write(path)


def cpu_model():
    out = subprocess.run(['lscpu'], capture_output=True, text=True).stdout
    for line in out.splitlines():
        if line.startswith('Model name'):
            return line.split(':', 1)[1].strip()
    return '?'


def tile_to(img, h, w):
    reps = (h // img.shape[0] + 1, w // img.shape[1] + 1, 1)
    return np.ascontiguousarray(np.tile(img, reps)[:h, :w])


def cmd_time(a):
    w, h = (int(v) for v in a.time.lower().split('x'))
    src = a.frame or os.path.join(HERE, '..', 'samples', 'frame_0000.exr')
    color, albedo, normal = (tile_to(im, h, w) for im in frame_images(src, a.color))
    den = Denoiser(h, w, a.threads, a.quality, not a.no_aux, a.clean_aux)
    den.load(color, albedo, normal)
    load0 = os.getloadavg()
    for _ in range(3):
        den.run()
    ts = []
    c0 = time.process_time()
    for _ in range(a.reps):
        t0 = time.perf_counter()
        den.run()
        ts.append((time.perf_counter() - t0) * 1e3)
    print('OIDN %s (pyoidn %s), RT filter, quality %s, %s, %dx%d tiled from %s'
          % (pyoidn.version.oidn_version, importlib.metadata.version('pyoidn'), a.quality,
             'colour only' if a.no_aux else 'colour + albedo + normal' + (' (cleanAux)' if a.clean_aux else ''),
             w, h, os.path.relpath(src)))
    print('CPU %s, %d logical CPUs, OIDN numThreads %d; load average before %s, after %s'
          % (cpu_model(), os.cpu_count(), den.threads, ' '.join('%.2f' % v for v in load0),
             ' '.join('%.2f' % v for v in os.getloadavg())))
    cpu = (time.process_time() - c0) * 1e3 / a.reps
    print('median %.1f ms, min %.1f ms, max %.1f ms of %d runs; process CPU time %.0f ms/run (all threads)'
          % (statistics.median(ts), min(ts), max(ts), a.reps, cpu))
    den.close()


def cmd_denoise(a):
    names = sorted(f for f in os.listdir(a.input) if f.startswith('frame_') and f.endswith('.exr'))
    if not names:
        raise SystemExit('no frame_*.exr in %s' % a.input)
    os.makedirs(a.output, exist_ok=True)
    den, total = None, 0.0
    for name in names:
        color, albedo, normal = frame_images(os.path.join(a.input, name), a.color)
        if den is None or den.color.shape != color.shape:
            if den is not None:
                den.close()
            den = Denoiser(color.shape[0], color.shape[1], a.threads, a.quality, not a.no_aux, a.clean_aux)
        den.load(color, albedo, normal)
        t0 = time.perf_counter()
        out = den.run()
        total += time.perf_counter() - t0
        write_rgb(os.path.join(a.output, name), out)
    print('OIDN %s, quality %s, %d threads: %d frames into %s, %.1f ms/frame'
          % (pyoidn.version.oidn_version, a.quality, den.threads, len(names), a.output, 1e3 * total / len(names)))
    den.close()


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('input', nargs='?', help='a directory of frame_NNNN.exr')
    p.add_argument('-o', '--output')
    p.add_argument('--quality', default='high', choices=sorted(QUALITIES))
    p.add_argument('--threads', type=int, default=0, help='OIDN numThreads (0: its default, all cores)')
    p.add_argument('--color', default='1spp', choices=['1spp', 'ab-mean'])
    p.add_argument('--no-aux', action='store_true', help='colour only (no albedo, no normal)')
    p.add_argument('--clean-aux', action='store_true', help="set cleanAux: albedo and normal are noise-free")
    p.add_argument('--time', metavar='WxH', help='time one frame of this size')
    p.add_argument('--reps', type=int, default=10)
    p.add_argument('--frame', help='the frame tiled for --time')
    a = p.parse_args()
    if a.time:
        if a.reps < 10:
            p.error('--reps must be at least 10')
        cmd_time(a)
    elif a.input and a.output:
        cmd_denoise(a)
    else:
        p.error('IN_DIR and -o OUT_DIR are needed (or --time WxH)')


if __name__ == '__main__':
    main()
