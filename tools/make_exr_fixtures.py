#!/usr/bin/env python3
"""Writes the EXR layout fixtures of cli/tests/layouts.rs with the OpenEXR
library itself (its PyPI package), not with the `exr` crate the loader
uses: the same two frames (a 64x48 crop of the corpus's glossy room, every
buffer) in the layouts production pipelines write.

    tools/.venv/bin/python tools/make_exr_fixtures.py [OUT]   (default tests/fixtures/layouts)

  plain/       one scan-line part, the input contract's names (the reference)
  multipart/   R,G,B in part 'rgba', every other buffer in part 'aovs'
  clash/       parts 'beauty' and 'albedo' both holding R,G,B (the first
               part's are the colour unless --part says; the albedo part
               answers to albedo.R/G/B), normals and the rest in 'aovs'
  blender/     Blender's multilayer naming under the view layer 'ViewLayer':
               Combined.R/G/B/A, Denoising Albedo, Normal, Position, Depth
               (1e10 where nothing is hit), Vector (X, Y: motion to the
               previous frame, y up; Z, W: to the next)
  window/      data window (10,10)-(73,57) inside a display window
               (0,0)-(83,67), pixel aspect 1.25, decreasing line order,
               chromaticities, a renderer string, a camera matrix, an alpha
               and a u32 object-id channel
  tiled_mip/   tiled 16x16 with mipmap levels (the loader reads level 0)
  separate/    frames/ with R,G,B (and depth, position, motion), and the
               albedo and normal as files of their own (albedo/, normal/,
               their R,G,B), matched by file name
Every pixel is an f16 value, so each layout carries exactly the same
numbers.
"""
import os
import sys

import numpy as np
import OpenEXR

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
SRC = os.path.join(ROOT, 'tests', 'fixtures', 'corpus', 'glossy')
X0, Y0, W, H = 48, 24, 64, 48

BUFFERS = {
    'colour': ['R', 'G', 'B'],
    'albedo': ['albedo.R', 'albedo.G', 'albedo.B'],
    'normal': ['normal.X', 'normal.Y', 'normal.Z'],
    'depth': ['depth.Z'],
    'position': ['position.X', 'position.Y', 'position.Z'],
    'motion': ['motion.X', 'motion.Y'],
}


def load(i):
    with OpenEXR.File(os.path.join(SRC, 'frame_%04d.exr' % i), separate_channels=True) as f:
        ch = {n: np.asarray(c.pixels) for n, c in f.channels().items()}
    out = {}
    for names in BUFFERS.values():
        for n in names:
            out[n] = np.ascontiguousarray(ch[n][Y0:Y0 + H, X0:X0 + W].astype(np.float16))
    return out


def write(path, parts, **header):
    """parts: list of (name or None, {channel: array}, extra header)."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    built = []
    for name, chans, extra in parts:
        h = {'compression': OpenEXR.ZIP_COMPRESSION, 'type': OpenEXR.scanlineimage}
        h.update(header)
        h.update(extra)
        if name is not None:
            h['name'] = name
        built.append(OpenEXR.Part(h, chans, name=name) if name is not None else (h, chans))
    if len(built) == 1 and not isinstance(built[0], OpenEXR.Part):
        with OpenEXR.File(built[0][0], built[0][1]) as f:
            f.write(path)
    else:
        with OpenEXR.File(built) as f:
            f.write(path)


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, 'tests', 'fixtures', 'layouts')
    for i in range(2):
        c = load(i)
        name = 'frame_%04d.exr' % i
        sel = lambda names: {n: c[n] for n in names}
        aov_names = [n for k, v in BUFFERS.items() if k != 'colour' for n in v]
        write(os.path.join(out, 'plain', name), [(None, dict(c), {})])
        write(os.path.join(out, 'multipart', name),
              [('rgba', sel(BUFFERS['colour']), {}), ('aovs', sel(aov_names), {})])
        rgb_of = lambda names: {k: c[n] for k, n in zip(['R', 'G', 'B'], names)}
        write(os.path.join(out, 'clash', name),
              [('beauty', sel(BUFFERS['colour']), {}), ('albedo', rgb_of(BUFFERS['albedo']), {}),
               ('aovs', sel([n for n in aov_names if not n.startswith('albedo')]), {})])
        L = 'ViewLayer.'
        depth = c['depth.Z'].astype(np.float32)
        depth = np.where(depth == 0, 1e10, depth).astype(np.float32)
        bl = {
            L + 'Combined.R': c['R'], L + 'Combined.G': c['G'], L + 'Combined.B': c['B'],
            L + 'Combined.A': np.ones((H, W), np.float16),
            L + 'Denoising Albedo.R': c['albedo.R'], L + 'Denoising Albedo.G': c['albedo.G'],
            L + 'Denoising Albedo.B': c['albedo.B'],
            L + 'Normal.X': c['normal.X'], L + 'Normal.Y': c['normal.Y'], L + 'Normal.Z': c['normal.Z'],
            L + 'Position.X': c['position.X'], L + 'Position.Y': c['position.Y'], L + 'Position.Z': c['position.Z'],
            L + 'Depth.Z': depth,
            L + 'Vector.X': c['motion.X'], L + 'Vector.Y': -c['motion.Y'],
            L + 'Vector.Z': -c['motion.X'], L + 'Vector.W': c['motion.Y'],
        }
        write(os.path.join(out, 'blender', name), [(None, bl, {'BlenderMultiChannel': 'Blender V2.55.1 and newer'})])
        win = dict(c)
        win['A'] = np.ones((H, W), np.float16)
        win['id'] = (np.arange(W * H, dtype=np.uint32).reshape(H, W) * 7919) % 65521
        write(os.path.join(out, 'window', name), [(None, win, {
            'dataWindow': ((10, 10), (10 + W - 1, 10 + H - 1)), 'displayWindow': ((0, 0), (83, 67)),
            'pixelAspectRatio': 1.25, 'lineOrder': OpenEXR.DECREASING_Y,
            'chromaticities': (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290),
            'renderer': 'mcdenoise fixture 1.0',
            'worldToCamera': np.arange(16, dtype=np.float32).reshape(4, 4),
        })])
        td = OpenEXR.TileDescription()
        td.xSize, td.ySize, td.mode, td.roundingMode = 16, 16, OpenEXR.MIPMAP_LEVELS, OpenEXR.ROUND_DOWN
        write(os.path.join(out, 'tiled_mip', name), [(None, dict(c), {'type': OpenEXR.tiledimage, 'tiles': td})])
        rest = [n for k, v in BUFFERS.items() if k not in ('albedo', 'normal') for n in v]
        write(os.path.join(out, 'separate', 'frames', name), [(None, sel(rest), {})])
        write(os.path.join(out, 'separate', 'albedo', name), [(None, rgb_of(BUFFERS['albedo']), {})])
        write(os.path.join(out, 'separate', 'normal', name), [(None, rgb_of(BUFFERS['normal']), {})])
    print('wrote the layout fixtures to %s' % out)


if __name__ == '__main__':
    main()
