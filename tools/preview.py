#!/usr/bin/env python3
"""Contact sheet PNG of one rendered frame: noisy A, noisy B, reference,
albedo, normal, depth, position, motion (for eyeballing render.py output).

    tools/.venv/bin/python tools/preview.py samples/frame_0003.exr out.png [--scale 2]
"""

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from exrio import read_exr, stack  # noqa: E402


def tonemap(rgb, exposure=1.0):
    x = np.clip(rgb * exposure, 0, None)
    x = x / (1 + x) * 1.6  # gentle Reinhard, brightened
    x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.clip(x, 0.0031308, None), 1 / 2.4) - 0.055)
    return np.clip(x, 0, 1)


def gray(x):
    return np.repeat(x[..., None], 3, axis=-1)


def normalized(x):
    lo, hi = np.percentile(x, 1), np.percentile(x, 99)
    return np.clip((x - lo) / max(hi - lo, 1e-9), 0, 1)


def motion_rgb(m):
    mag = np.linalg.norm(m, axis=-1)
    scale = max(np.percentile(mag, 99), 1e-6)
    return np.clip(np.stack([0.5 + 0.5 * m[..., 0] / scale, 0.5 + 0.5 * m[..., 1] / scale,
                             np.full(mag.shape, 0.5)], -1), 0, 1)


def main():
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('frame')
    p.add_argument('png')
    p.add_argument('--scale', type=int, default=2)
    a = p.parse_args()
    ch = read_exr(a.frame)
    ref_path = os.path.join(os.path.dirname(a.frame), 'ref', os.path.basename(a.frame))
    tiles = [tonemap(stack(ch, ['R', 'G', 'B'])), tonemap(stack(ch, ['B.R', 'B.G', 'B.B']))]
    if os.path.exists(ref_path):
        tiles.append(tonemap(stack(read_exr(ref_path), ['R', 'G', 'B'])))
    else:
        tiles.append(np.zeros_like(tiles[0]))
    tiles.append(np.clip(stack(ch, ['albedo.R', 'albedo.G', 'albedo.B']), 0, 1) ** (1 / 2.2))
    tiles.append(np.clip(0.5 + 0.5 * stack(ch, ['normal.X', 'normal.Y', 'normal.Z']), 0, 1))
    tiles.append(gray(normalized(ch['depth.Z'])))
    tiles.append(np.clip(np.stack([normalized(ch['position.' + c]) for c in 'XYZ'], -1), 0, 1))
    tiles.append(motion_rgb(stack(ch, ['motion.X', 'motion.Y'])))
    h, w = tiles[0].shape[:2]
    rows = [np.concatenate(tiles[i:i + 4], axis=1) for i in (0, 4)]
    sheet = np.concatenate(rows, axis=0)
    sheet = np.repeat(np.repeat(sheet, a.scale, axis=0), a.scale, axis=1)
    img = (sheet * 255 + 0.5).astype(np.uint8)
    write_png(a.png, img)
    print('wrote %s (%dx%d); tiles: noisy A, noisy B, reference, albedo / normal, depth, '
          'position, motion' % (a.png, img.shape[1], img.shape[0]))


def write_png(path, img):
    import struct
    import zlib
    h, w, _ = img.shape
    raw = b''.join(b'\x00' + img[y].tobytes() for y in range(h))

    def chunk(tag, data):
        c = struct.pack('>I', len(data)) + tag + data
        return c + struct.pack('>I', zlib.crc32(tag + data) & 0xffffffff)

    with open(path, 'wb') as f:
        f.write(b'\x89PNG\r\n\x1a\n')
        f.write(chunk(b'IHDR', struct.pack('>IIBBBBB', w, h, 8, 2, 0, 0, 0)))
        f.write(chunk(b'IDAT', zlib.compress(raw, 9)))
        f.write(chunk(b'IEND', b''))


if __name__ == '__main__':
    main()
