#!/usr/bin/env python3
"""Procedural scenes for training the learned denoisers (and held-out scenes
of the same generator for validation and testing).

    python3 tools/gen_scenes.py --out DIR/scenes --split train --count 400 --seed 1

writes DIR/scenes/train_NNNN.json (one scene file per sequence, for
tools/render.py), and the textures and environment maps they use under
DIR/scenes/assets/. Everything follows from (--seed, --split, index): the
same command writes the same files. The scene of index i does not depend on
--count, so a larger --count only adds scenes.

What a scene draws from (each an independent choice per scene):
  set        a room (walls, optional ceiling and front wall, furniture),
             an open scene (ground, sky and sun or an environment map,
             many objects, buildings, poles), or a studio (floor, backdrop,
             a few objects under soft boxes)
  objects    spheres, boxes, cylinders, disks, thin rods and slats, tables,
             shelves; 3 to 24 of them
  materials  diffuse (near-black 0.001-0.02 and near-white 0.85-0.95
             included), textured diffuse (checkers, noise, stripes, tiles,
             wood rings), rough and smooth plastic, rough and smooth metals
             (Au, Ag, Cu, Al, Cr, W, Ni, TiN, Mo), glass (smooth, rough, thin)
  lights     ceiling and wall panels, visible bulbs (spheres), point, spot,
             sun and sky, environment maps; 10^-1.3 to 10^1 around a
             calibrated power, so scenes run from very dim to very bright
  camera     fixed, pan, orbit, dolly, truck, hand-held shake; field of view
             35-75 degrees
  motion     moving objects and moving lights (keyframes)
  noise      1 spp (half the scenes) or 2, 4, 8, 16 spp per estimate;
             --spp draws from a given list instead (the `hi` part: 16,
             32, 64), the AOVs at as many samples, from 16 up
  albedo     the directional reflectance or Mitsuba's raw albedo AOV
             (`"albedo"` of the scene file, read by render.py)

Split seeds: train, val and test draw from disjoint seed streams.
"""
import argparse
import json
import math
import os
import struct
import zlib

import numpy as np

SPLITS = {'train': 1, 'val': 2, 'test': 3, 'hi': 4}
METALS = ['Au', 'Ag', 'Cu', 'Al', 'Cr', 'W', 'Ni_palik', 'TiN', 'Mo']


# -----------------------------------------------------------------------------
# Assets: textures (8-bit sRGB PNG) and environment maps (float EXR)
# -----------------------------------------------------------------------------

def write_png(path, img):
    """img: (H, W, 3) floats in [0, 1], written as 8-bit RGB PNG (sRGB values)."""
    a = (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)
    h, w, _ = a.shape
    raw = b''.join(b'\x00' + a[y].tobytes() for y in range(h))

    def chunk(kind, data):
        c = struct.pack('>I', len(data)) + kind + data
        return c + struct.pack('>I', zlib.crc32(kind + data) & 0xffffffff)

    png = b'\x89PNG\r\n\x1a\n' + chunk(b'IHDR', struct.pack('>IIBBBBB', w, h, 8, 2, 0, 0, 0))
    png += chunk(b'IDAT', zlib.compress(raw, 9)) + chunk(b'IEND', b'')
    with open(path, 'wb') as f:
        f.write(png)


def value_noise(rng, n, octaves=5):
    out = np.zeros((n, n))
    amp, tot = 1.0, 0.0
    for o in range(octaves):
        g = 2 ** (o + 2)
        grid = rng.random((g + 1, g + 1))
        grid[-1, :] = grid[0, :]
        grid[:, -1] = grid[:, 0]
        t = np.linspace(0, g, n, endpoint=False)
        i = t.astype(int)
        f = t - i
        f = f * f * (3 - 2 * f)
        a = grid[i][:, i] * (1 - f)[None, :] + grid[i][:, i + 1] * f[None, :]
        b = grid[i + 1][:, i] * (1 - f)[None, :] + grid[i + 1][:, i + 1] * f[None, :]
        out += amp * (a * (1 - f)[:, None] + b * f[:, None])
        tot += amp
        amp *= 0.55
    return out / tot


def texture_image(rng, kind, n=256):
    c0, c1 = rand_colour(rng), rand_colour(rng)
    yy, xx = np.mgrid[0:n, 0:n] / n
    if kind == 'noise':
        t = value_noise(rng, n)
        t = (t - t.min()) / max(1e-9, np.ptp(t))
    elif kind == 'stripes':
        k = rng.integers(3, 12)
        ang = rng.uniform(0, math.pi)
        t = (np.sin(2 * math.pi * k * (xx * math.cos(ang) + yy * math.sin(ang))) > rng.uniform(-0.5, 0.5)) * 1.0
    elif kind == 'tiles':
        k = int(rng.integers(4, 16))
        grout = rng.uniform(0.03, 0.12)
        fx, fy = (xx * k) % 1, (yy * k) % 1
        t = ((fx > grout) & (fy > grout)) * 1.0
        t *= 0.75 + 0.25 * value_noise(rng, n, 3)
    elif kind == 'wood':
        cx, cy = rng.uniform(-1, 2, 2)
        r = np.sqrt((xx - cx) ** 2 * 0.05 + (yy - cy) ** 2) * rng.uniform(20, 60)
        t = 0.5 + 0.5 * np.sin(r + 3 * value_noise(rng, n, 3))
    elif kind == 'blotches':
        t = (value_noise(rng, n, 4) > 0.5) * 1.0
    else:  # dots
        k = int(rng.integers(4, 14))
        fx, fy = (xx * k) % 1 - 0.5, (yy * k) % 1 - 0.5
        t = (fx * fx + fy * fy < rng.uniform(0.02, 0.15)) * 1.0
    img = c0[None, None, :] * (1 - t[..., None]) + c1[None, None, :] * t[..., None]
    return img ** (1 / 2.2)  # stored as sRGB-ish: Mitsuba linearises 8-bit PNGs


def write_exr(path, img):
    import OpenEXR
    chans = {c: np.ascontiguousarray(img[..., i].astype(np.float32)) for i, c in enumerate('RGB')}
    with OpenEXR.File({'compression': OpenEXR.ZIP_COMPRESSION, 'type': OpenEXR.scanlineimage}, chans) as f:
        f.write(path)


def sky_image(rng, w=256, h=128):
    """Lat-long sky: horizon-to-zenith gradient, a ground colour and a sun disc."""
    v = (np.arange(h) + 0.5) / h  # 0 = top (zenith) .. 1 = bottom
    u = (np.arange(w) + 0.5) / w
    elev = (0.5 - v) * math.pi  # radians above the horizon
    zen = np.array([0.15, 0.3, 0.8]) * rng.uniform(0.3, 1.5)
    hor = np.array([0.8, 0.85, 0.9]) * rng.uniform(0.4, 1.5)
    gnd = rand_colour(rng) * rng.uniform(0.05, 0.4)
    s = np.clip(np.sin(np.maximum(elev, 0)), 0, 1) ** 0.5
    row = np.where(elev[:, None] > 0, hor[None, :] * (1 - s[:, None]) + zen[None, :] * s[:, None], gnd[None, :])
    img = np.repeat(row[:, None, :], w, axis=1)
    if rng.random() < 0.8:  # a sun
        su, se = rng.uniform(0, 1), rng.uniform(0.1, 1.2)
        d_ang = np.sqrt(((u[None, :] - su + 0.5) % 1 - 0.5) ** 2 * (2 * math.pi) ** 2 * np.cos(elev[:, None]) ** 2
                        + (elev[:, None] - se) ** 2)
        sun = np.exp(-(d_ang / rng.uniform(0.02, 0.05)) ** 2) * rng.uniform(200, 3000)
        img = img + sun[..., None] * np.array([1.0, 0.92, 0.8])[None, None, :]
    if rng.random() < 0.5:  # clouds
        c = np.clip(value_noise(rng, w, 5)[:h] - 0.45, 0, 1) * 2
        img = img * (1 - c[..., None] * 0.6) + c[..., None] * hor[None, None, :] * 1.2 * (elev[:, None, None] > 0)
    return img


def make_assets(adir, seed):
    """The texture and environment-map banks (deterministic from seed)."""
    os.makedirs(adir, exist_ok=True)
    rng = np.random.default_rng([seed, 99])
    tex = []
    kinds = ['noise', 'stripes', 'tiles', 'wood', 'blotches', 'dots']
    for i in range(36):
        p = os.path.join(adir, 'tex_%02d.png' % i)
        img = texture_image(rng, kinds[i % len(kinds)])
        if not os.path.exists(p):
            write_png(p, img)
        tex.append(p)
    env = []
    for i in range(10):
        p = os.path.join(adir, 'sky_%02d.exr' % i)
        img = sky_image(rng)
        if not os.path.exists(p):
            write_exr(p, img)
        env.append(p)
    return tex, env


# -----------------------------------------------------------------------------
# Random materials
# -----------------------------------------------------------------------------

def rand_colour(rng, kind=None):
    """A linear reflectance: mostly mid-range colours, some near-black, some near-white."""
    kind = kind or rng.choice(['mid', 'mid', 'mid', 'mid', 'dark', 'black', 'white', 'grey'])
    if kind == 'black':
        return np.full(3, rng.uniform(0.001, 0.02)) * rng.uniform(0.8, 1.2, 3)
    if kind == 'white':
        return np.full(3, rng.uniform(0.85, 0.95)) * rng.uniform(0.97, 1.0, 3)
    if kind == 'grey':
        return np.full(3, rng.uniform(0.05, 0.8))
    if kind == 'dark':
        v = rng.uniform(0.02, 0.08)
    else:
        v = rng.uniform(0.1, 0.85)
    h, s = rng.uniform(0, 1), rng.uniform(0, 0.9)
    rgb = np.array([abs(((h * 6 + k) % 6) - 3) - 1 for k in (0, 4, 2)]).clip(0, 1)
    return np.clip(v * (1 - s + s * rgb), 0.0005, 0.98)


def col(c):
    return [round(float(x), 5) for x in c]


class Materials:
    def __init__(self, rng, textures):
        self.rng, self.textures = rng, textures

    def texture(self):
        rng = self.rng
        if rng.random() < 0.35:
            s = float(rng.uniform(2, 24))
            return {'type': 'checkerboard', 'color0': col(rand_colour(rng)), 'color1': col(rand_colour(rng)),
                    'to_uv': {'scale': [s, s]}}
        s = float(rng.uniform(0.5, 6))
        return {'type': 'bitmap', 'filename': str(rng.choice(self.textures)), 'to_uv': {'scale': [s, s]}}

    def diffuse(self, textured=None):
        rng = self.rng
        textured = rng.random() < 0.3 if textured is None else textured
        refl = self.texture() if textured else col(rand_colour(rng))
        return {'type': 'diffuse', 'twosided': True, 'reflectance': refl}

    def any(self, weights=None):
        rng = self.rng
        kinds = ['diffuse', 'textured', 'plastic', 'glossy', 'metal', 'mirror', 'glass']
        w = np.array(weights or [0.30, 0.14, 0.14, 0.1, 0.16, 0.06, 0.10], dtype=float)
        k = kinds[rng.choice(len(kinds), p=w / w.sum())]
        if k == 'diffuse':
            return self.diffuse(False)
        if k == 'textured':
            return self.diffuse(True)
        if k in ('plastic', 'glossy'):
            dif = self.texture() if rng.random() < 0.2 else col(rand_colour(rng))
            if k == 'glossy' and rng.random() < 0.5:
                return {'type': 'plastic', 'diffuse_reflectance': dif, 'int_ior': float(rng.uniform(1.3, 1.7))}
            a = float(rng.uniform(0.02, 0.08) if k == 'glossy' else rng.uniform(0.08, 0.5))
            return {'type': 'roughplastic', 'distribution': 'ggx', 'alpha': round(a, 4), 'diffuse_reflectance': dif,
                    'int_ior': 1.5}
        if k == 'metal':
            return {'type': 'roughconductor', 'material': str(rng.choice(METALS)), 'distribution': 'ggx',
                    'alpha': round(float(math.exp(rng.uniform(math.log(0.02), math.log(0.6)))), 4)}
        if k == 'mirror':
            return {'type': 'conductor', 'material': str(rng.choice(METALS))}
        r = rng.random()
        if r < 0.6:
            return {'type': 'dielectric', 'int_ior': round(float(rng.uniform(1.3, 1.8)), 3)}
        if r < 0.85:
            return {'type': 'roughdielectric', 'distribution': 'ggx', 'alpha': round(float(rng.uniform(0.05, 0.4)), 3),
                    'int_ior': 1.5}
        return {'type': 'thindielectric', 'int_ior': 1.5}

    def wall(self):
        return self.any([0.55, 0.3, 0.08, 0.03, 0.02, 0.0, 0.02])

    def floor(self):
        return self.any([0.3, 0.4, 0.12, 0.12, 0.04, 0.0, 0.02])


BLACK = {'type': 'diffuse', 'reflectance': [0.0, 0.0, 0.0]}


# -----------------------------------------------------------------------------
# Scene building blocks
# -----------------------------------------------------------------------------

class Builder:
    def __init__(self, rng, mats):
        self.rng, self.mats = rng, mats
        self.shapes, self.emitters = [], []

    def add(self, kind, mat, scale, translate, rotate=None, keys=None, prefix='s', emitter=None):
        t = {'scale': scale, 'translate': [round(float(v), 4) for v in translate]}
        if rotate:
            t['rotate'] = rotate
        s = {'id': '%s%d' % (prefix, len(self.shapes)), 'type': kind, 'material': mat, 'transform': t}
        if keys:
            s['keyframes'] = keys
        if emitter is not None:
            s['emitter'] = {'type': 'area', 'radiance': col(emitter)}
        self.shapes.append(s)
        return s

    def box(self, mat, half, centre, yaw=0.0, **kw):
        return self.add('cube', mat, [round(float(v), 4) for v in half], centre,
                        rotate=[0, 1, 0, round(float(yaw), 2)] if yaw else None, **kw)

    def object(self, at, size, mat=None, moving=None):
        """A random object standing on the plane y = at[1] at (x, z)."""
        rng = self.rng
        mat = mat or self.mats.any()
        x, y0, z = at
        kind = rng.choice(['sphere', 'sphere', 'box', 'box', 'cylinder', 'rod', 'slats', 'disk', 'table', 'shelf'])
        keys = None
        if moving is not None:
            dx, dz = moving
            keys = [{'t': 0, 'translate': None}, {'t': 1, 'translate': None}]
        if kind == 'sphere':
            r = size * rng.uniform(0.3, 0.6)
            c = [x, y0 + r, z]
            if keys:
                keys = [{'t': 0, 'translate': c}, {'t': 1, 'translate': [x + dx, y0 + r, z + dz]}]
            self.add('sphere', mat, round(float(r), 4), c, keys=keys)
        elif kind == 'box':
            half = [size * rng.uniform(0.15, 0.6), size * rng.uniform(0.15, 0.8), size * rng.uniform(0.15, 0.6)]
            c = [x, y0 + half[1], z]
            if keys:
                keys = [{'t': 0, 'translate': c}, {'t': 1, 'translate': [x + dx, c[1], z + dz]}]
            self.box(mat, half, c, yaw=rng.uniform(0, 90), keys=keys)
        elif kind == 'cylinder':
            r, h = size * rng.uniform(0.1, 0.35), size * rng.uniform(0.3, 1.5)
            self.add('cylinder', mat, [round(float(r), 4), round(float(r), 4), round(float(h), 4)], [x, y0, z],
                     rotate=[1, 0, 0, -90])
            self.add('disk', mat, round(float(r), 4), [x, y0 + h, z], rotate=[1, 0, 0, -90])
        elif kind == 'rod':  # thin features
            n = int(rng.integers(1, 6))
            r = rng.uniform(0.004, 0.02)
            h = size * rng.uniform(0.8, 2.5)
            for i in range(n):
                self.add('cylinder', mat, [round(float(r), 4), round(float(r), 4), round(float(h), 4)],
                         [x + i * size * 0.15, y0, z + rng.uniform(-0.05, 0.05)],
                         rotate=[[1, 0, 0, -90], [0, 0, 1, round(float(rng.uniform(-25, 25)), 2)]])
        elif kind == 'slats':
            n = int(rng.integers(3, 9))
            for i in range(n):
                self.box(mat, [size * 0.6, rng.uniform(0.005, 0.02), size * 0.04],
                         [x, y0 + 0.1 + i * size * 0.12, z], yaw=rng.uniform(-10, 10))
        elif kind == 'disk':
            r = size * rng.uniform(0.3, 0.7)
            self.add('disk', mat, round(float(r), 4), [x, y0 + 0.003, z], rotate=[1, 0, 0, -90])
        elif kind == 'table':
            top_y = size * rng.uniform(0.6, 1.0)
            hw, hd = size * rng.uniform(0.4, 0.9), size * rng.uniform(0.3, 0.6)
            self.box(mat, [hw, 0.025, hd], [x, y0 + top_y, z])
            leg = self.mats.any([0.5, 0.1, 0.1, 0.0, 0.3, 0.0, 0.0])
            for sx, sz in ((-1, -1), (1, -1), (-1, 1), (1, 1)):
                self.add('cylinder', leg, [0.025, 0.025, round(float(top_y), 4)],
                         [x + sx * (hw - 0.05), y0, z + sz * (hd - 0.05)], rotate=[1, 0, 0, -90])
            if rng.random() < 0.7:  # something on it
                self.object([x + rng.uniform(-hw, hw) * 0.5, y0 + top_y + 0.025, z], size * 0.35)
        else:  # shelf
            hw, h = size * rng.uniform(0.4, 0.8), size * rng.uniform(1.0, 2.0)
            for i in range(int(rng.integers(2, 5))):
                self.box(mat, [hw, 0.015, size * 0.2], [x, y0 + 0.1 + i * h / 4, z])
            for sx in (-1, 1):
                self.box(mat, [0.015, h / 2, size * 0.2], [x + sx * hw, y0 + h / 2, z])

    def panel(self, radiance, half, centre, rotate, keys=None):
        """A one-sided emitting rectangle (black on its back)."""
        return self.add('rectangle', BLACK, [round(float(v), 4) for v in half] + [1], centre, rotate=rotate,
                        keys=keys, prefix='light', emitter=radiance)

    def bulb(self, radiance, r, centre, keys=None):
        return self.add('sphere', BLACK, round(float(r), 4), centre, keys=keys, prefix='light', emitter=radiance)


def light_colour(rng):
    t = rng.choice(['white', 'warm', 'cool', 'tint'], p=[0.4, 0.3, 0.2, 0.1])
    if t == 'white':
        return np.ones(3)
    if t == 'warm':
        return np.array([1.0, rng.uniform(0.75, 0.9), rng.uniform(0.5, 0.75)])
    if t == 'cool':
        return np.array([rng.uniform(0.7, 0.9), rng.uniform(0.85, 0.95), 1.0])
    c = rand_colour(rng, 'mid')
    return c / c.max()


def keyed(rng, base, amount, frames_t=(0.0, 1.0)):
    """Keyframes moving `base` by a random vector of length `amount`."""
    d = rng.normal(size=3)
    d[1] *= 0.3
    d = d / max(1e-9, np.linalg.norm(d)) * amount
    return [{'t': frames_t[0], 'translate': [round(float(v), 4) for v in base]},
            {'t': frames_t[1], 'translate': [round(float(v), 4) for v in np.asarray(base) + d]}]


# -----------------------------------------------------------------------------
# Sets
# -----------------------------------------------------------------------------

def room_set(rng, b, exposure):
    mats = b.mats
    w, d, h = rng.uniform(1.5, 4.5), rng.uniform(1.5, 4.5), rng.uniform(2.3, 3.8)
    floor = mats.floor()
    wall = mats.wall() if rng.random() < 0.5 else None
    b.add('rectangle', floor, [round(w, 3), round(d, 3), 1], [0, 0, 0], rotate=[1, 0, 0, -90], prefix='floor')
    walls = [([w, h / 2, 1], [0, h / 2, -d], None),
             ([d, h / 2, 1], [-w, h / 2, 0], [0, 1, 0, 90]),
             ([d, h / 2, 1], [w, h / 2, 0], [0, 1, 0, -90])]
    if rng.random() < 0.4:
        walls.append(([w, h / 2, 1], [0, h / 2, d], [0, 1, 0, 180]))
    for half, c, rot in walls:
        b.add('rectangle', wall or mats.wall(), [round(v, 3) for v in half], c, rotate=rot, prefix='wall')
    ceiling = rng.random() < 0.8
    if ceiling:
        b.add('rectangle', mats.diffuse(False), [round(w, 3), round(d, 3), 1], [0, h, 0], rotate=[1, 0, 0, 90],
              prefix='ceil')
    nobj = int(rng.integers(3, 14))
    for _ in range(nobj):
        x, z = rng.uniform(-w * 0.85, w * 0.85), rng.uniform(-d * 0.9, d * 0.4)
        moving = None
        if rng.random() < 0.15:
            moving = tuple(rng.uniform(-0.6, 0.6, 2))
        b.object([x, 0.0, z], rng.uniform(0.3, 1.0), moving=moving)
    # lights: total power ~ 60 W-ish x exposure, shared out
    nl = int(rng.choice([1, 1, 2, 2, 3]))
    power = 60.0 * exposure * (w * d) / 9.0
    move_light = rng.random() < 0.3
    for i in range(nl):
        p = power / nl * rng.uniform(0.5, 1.5)
        c = light_colour(rng)
        kind = rng.choice(['ceiling', 'ceiling', 'bulb', 'point', 'spot', 'wallpanel'])
        keys = None
        if kind == 'ceiling' and ceiling:
            sx, sz = rng.uniform(0.08, 1.0), rng.uniform(0.08, 1.0)
            pos = [rng.uniform(-w / 2, w / 2), h - 0.005, rng.uniform(-d * 0.8, d * 0.3)]
            if move_light and i == 0:
                keys = keyed(rng, pos, rng.uniform(0.5, 2.0))
                for k in keys:
                    k['translate'][1] = round(h - 0.005, 4)
            b.panel(c * p / (math.pi * 4 * sx * sz), [sx, sz], pos, [1, 0, 0, 90], keys=keys)
        elif kind == 'wallpanel':
            sx, sy = rng.uniform(0.1, 0.6), rng.uniform(0.1, 0.6)
            pos = [rng.uniform(-w / 2, w / 2), rng.uniform(0.8, h - 0.5), -d + 0.005]
            b.panel(c * p / (math.pi * 4 * sx * sy), [sx, sy], pos, None)
        elif kind in ('bulb', 'ceiling'):
            r = rng.uniform(0.02, 0.15)
            pos = [rng.uniform(-w * 0.7, w * 0.7), rng.uniform(0.5, h - 0.3), rng.uniform(-d * 0.8, d * 0.2)]
            if move_light and i == 0:
                keys = keyed(rng, pos, rng.uniform(0.5, 2.0))
            b.bulb(c * p / (math.pi * 4 * math.pi * r * r), r, pos, keys=keys)
        elif kind == 'point':
            pos = [rng.uniform(-w * 0.7, w * 0.7), rng.uniform(0.8, h - 0.2), rng.uniform(-d * 0.8, d * 0.3)]
            e = {'type': 'point', 'intensity': col(c * p / (4 * math.pi)), 'position': [round(v, 4) for v in pos]}
            if move_light and i == 0:
                e['keyframes'] = [{'t': 0, 'position': e['position']},
                                  {'t': 1, 'position': keyed(rng, pos, rng.uniform(0.5, 2.0))[1]['translate']}]
            b.emitters.append(e)
        else:
            org = [rng.uniform(-w * 0.8, w * 0.8), h - 0.1, rng.uniform(-d * 0.5, d * 0.8)]
            tgt = [rng.uniform(-w * 0.6, w * 0.6), 0.0, rng.uniform(-d * 0.9, 0)]
            ang = rng.uniform(15, 45)
            e = {'type': 'spot', 'intensity': col(c * p / (2 * math.pi * (1 - math.cos(math.radians(ang))))),
                 'origin': [round(v, 4) for v in org], 'target': [round(v, 4) for v in tgt],
                 'cutoff_angle': round(ang, 2), 'beam_width': round(ang * rng.uniform(0.5, 0.9), 2)}
            if move_light and i == 0:
                e['keyframes'] = [{'t': 0, 'target': e['target']},
                                  {'t': 1, 'target': [round(tgt[0] + rng.uniform(-1.5, 1.5), 4), 0.0,
                                                      round(tgt[2] + rng.uniform(-1.5, 1.5), 4)]}]
            b.emitters.append(e)
    if not ceiling and rng.random() < 0.7:  # open to the sky
        b.emitters.append({'type': 'constant', 'radiance': col(np.array([0.5, 0.6, 0.8]) * 0.3 * exposure)})
    # camera inside, looking into the room
    origin = np.array([rng.uniform(-w * 0.6, w * 0.6), rng.uniform(0.6, min(2.0, h - 0.3)), rng.uniform(0.3, 0.9) * d])
    target = np.array([rng.uniform(-w * 0.5, w * 0.5), rng.uniform(0.2, 1.4), rng.uniform(-d, -d * 0.2)])
    return origin, target, (w, d, h)


def open_set(rng, b, exposure, envmaps):
    mats = b.mats
    b.add('rectangle', mats.floor(), [40, 40, 1], [0, 0, 0], rotate=[1, 0, 0, -90], prefix='ground')
    n = int(rng.integers(6, 22))
    for _ in range(n):
        r = rng.uniform(1.0, 9.0)
        a = rng.uniform(0, 2 * math.pi)
        x, z = r * math.cos(a), -abs(r * math.sin(a)) * rng.choice([1, 1, 1, -1])
        if rng.random() < 0.25:  # a building
            half = [rng.uniform(0.5, 2.0), rng.uniform(1.0, 4.0), rng.uniform(0.5, 2.0)]
            b.box(mats.wall(), half, [x * 2, half[1], z * 2], yaw=rng.uniform(0, 90))
        else:
            moving = tuple(rng.uniform(-1, 1, 2)) if rng.random() < 0.12 else None
            b.object([x, 0.0, z], rng.uniform(0.4, 1.5), moving=moving)
    if rng.random() < 0.5:
        b.emitters.append({'type': 'envmap', 'filename': str(rng.choice(envmaps)),
                           'scale': round(float(0.5 * exposure), 5),
                           'to_world': {'rotate': [0, 1, 0, round(float(rng.uniform(0, 360)), 2)]}})
    else:
        sky = np.array([0.45, 0.6, 0.95]) * rng.uniform(0.2, 1.0)
        b.emitters.append({'type': 'constant', 'radiance': col(sky * exposure)})
        if rng.random() < 0.85:
            el, az = math.radians(rng.uniform(8, 75)), rng.uniform(0, 2 * math.pi)
            dr = [-math.cos(el) * math.cos(az), -math.sin(el), -math.cos(el) * math.sin(az)]
            sun = light_colour(rng) * rng.uniform(1.5, 6.0) * exposure
            e = {'type': 'directional', 'irradiance': col(sun), 'direction': [round(v, 5) for v in dr]}
            b.emitters.append(e)
    if rng.random() < 0.3:  # street lamps / bulbs in view
        for _ in range(int(rng.integers(1, 4))):
            r = rng.uniform(0.05, 0.2)
            b.bulb(light_colour(rng) * rng.uniform(20, 400) * exposure, r,
                   [rng.uniform(-5, 5), rng.uniform(1.5, 3.5), rng.uniform(-8, -1)])
    origin = np.array([rng.uniform(-3, 3), rng.uniform(0.5, 3.0), rng.uniform(3, 8)])
    target = np.array([rng.uniform(-2, 2), rng.uniform(0.0, 1.5), rng.uniform(-4, 0)])
    return origin, target, (8, 8, 4)


def studio_set(rng, b, exposure, envmaps):
    mats = b.mats
    back = mats.diffuse(rng.random() < 0.3)
    b.add('rectangle', back, [6, 6, 1], [0, 0, 0], rotate=[1, 0, 0, -90], prefix='floor')
    b.add('rectangle', back, [6, 3, 1], [0, 3, -3], prefix='backdrop')
    n = int(rng.integers(1, 6))
    for _ in range(n):
        moving = tuple(rng.uniform(-0.5, 0.5, 2)) if rng.random() < 0.2 else None
        b.object([rng.uniform(-1.5, 1.5), 0.0, rng.uniform(-1.5, 0.8)], rng.uniform(0.4, 1.2), moving=moving)
    move_light = rng.random() < 0.35
    for i in range(int(rng.integers(1, 4))):
        ang = rng.uniform(-80, 80)
        rad = rng.uniform(2.0, 4.0)
        pos = [rad * math.sin(math.radians(ang)), rng.uniform(1.0, 3.5), rad * math.cos(math.radians(ang)) - 1]
        sx, sy = rng.uniform(0.1, 1.0), rng.uniform(0.1, 1.0)
        p = 40.0 * exposure * rng.uniform(0.5, 1.5)
        keys = keyed(rng, pos, rng.uniform(0.5, 2.0)) if (move_light and i == 0) else None
        # face the origin: yaw towards the centre, tilt down
        yaw = math.degrees(math.atan2(-pos[0], -(pos[2] + 1)))
        b.panel(light_colour(rng) * p / (math.pi * 4 * sx * sy), [sx, sy], pos,
                [[1, 0, 0, round(float(rng.uniform(10, 40)), 2)], [0, 1, 0, round(yaw, 2)]], keys=keys)
    if rng.random() < 0.4:
        b.emitters.append({'type': 'envmap', 'filename': str(rng.choice(envmaps)),
                           'scale': round(float(0.2 * exposure), 5)})
    origin = np.array([rng.uniform(-2, 2), rng.uniform(0.5, 2.5), rng.uniform(2.5, 5.0)])
    target = np.array([rng.uniform(-0.5, 0.5), rng.uniform(0.2, 1.0), rng.uniform(-1.0, 0.0)])
    return origin, target, (3, 3, 3)


def camera_path(rng, origin, target, extent):
    """Keyframes of a random camera motion (or none)."""
    kind = rng.choice(['fixed', 'pan', 'orbit', 'dolly', 'truck', 'shake'], p=[0.15, 0.25, 0.2, 0.15, 0.15, 0.1])
    o, t = origin.copy(), target.copy()
    scale = min(extent[0], extent[1])
    keys = [{'t': 0, 'origin': o.tolist(), 'target': t.tolist()}]
    if kind == 'pan':
        ang = math.radians(rng.uniform(5, 30)) * rng.choice([-1, 1])
        v = t - o
        c, s = math.cos(ang), math.sin(ang)
        t2 = o + np.array([c * v[0] - s * v[2], v[1] + rng.uniform(-0.3, 0.3), s * v[0] + c * v[2]])
        keys.append({'t': 1, 'origin': o.tolist(), 'target': t2.tolist()})
    elif kind == 'orbit':
        ang = math.radians(rng.uniform(10, 50)) * rng.choice([-1, 1])
        v = o - t
        c, s = math.cos(ang), math.sin(ang)
        o2 = t + np.array([c * v[0] - s * v[2], v[1], s * v[0] + c * v[2]])
        keys.append({'t': 1, 'origin': o2.tolist(), 'target': t.tolist()})
    elif kind == 'dolly':
        f = rng.uniform(0.1, 0.4) * rng.choice([-1, 1])
        keys.append({'t': 1, 'origin': (o + f * (t - o)).tolist(), 'target': t.tolist()})
    elif kind == 'truck':
        d = rng.normal(size=3)
        d[1] *= 0.2
        d = d / np.linalg.norm(d) * rng.uniform(0.1, 0.3) * scale
        keys.append({'t': 1, 'origin': (o + d).tolist(), 'target': (t + d).tolist()})
    elif kind == 'shake':
        keys = []
        for i in range(5):
            j = rng.normal(size=3) * 0.02 * scale
            keys.append({'t': i / 4, 'origin': (o + j).tolist(), 'target': (t + j * 0.5).tolist()})
    for k in keys:
        k['origin'] = [round(float(v), 4) for v in k['origin']]
        k['target'] = [round(float(v), 4) for v in k['target']]
    return str(kind), keys


def make_scene(split, seed, index, textures, envmaps, res, frames, ref_spp, spp_choices=None):
    rng = np.random.default_rng([seed, SPLITS[split], index])
    b = Builder(rng, Materials(rng, textures))
    exposure = float(10 ** rng.uniform(-1.3, 1.0))
    kind = rng.choice(['room', 'open', 'studio'], p=[0.5, 0.3, 0.2])
    if kind == 'room':
        origin, target, extent = room_set(rng, b, exposure)
    elif kind == 'open':
        origin, target, extent = open_set(rng, b, exposure, envmaps)
    else:
        origin, target, extent = studio_set(rng, b, exposure, envmaps)
    motion, keys = camera_path(rng, origin, target, extent)
    if kind == 'room':  # keep the camera inside the room (an orbit could leave it)
        w, d, h = extent
        for k in keys:
            o = k['origin']
            k['origin'] = [round(min(max(o[0], -w + 0.15), w - 0.15), 4), round(min(max(o[1], 0.2), h - 0.15), 4),
                           round(min(max(o[2], -d + 0.15), d - 0.15), 4)]
    spp = int(rng.choice([1, 1, 1, 1, 1, 2, 4, 8, 16][:9]))
    if spp_choices:  # drawn apart, so that the scene is the same whatever the choices
        spp = int(np.random.default_rng([seed, SPLITS[split], index, 1]).choice(spp_choices))
    albedo = 'mitsuba' if rng.random() < 0.5 else 'reflectance'
    return {
        'description': 'generated (tools/gen_scenes.py): split %s, seed %d, index %d: %s set, camera %s, '
                       '%d shapes, %d emitters, exposure %.3g, %d spp, albedo %s'
                       % (split, seed, index, kind, motion, len(b.shapes), len(b.emitters), exposure, spp, albedo),
        'resolution': list(res), 'frames': frames, 'spp': spp, 'ref_spp': ref_spp, 'aov_spp': max(16, spp),
        'seed': int(rng.integers(1, 2 ** 31)), 'max_depth': int(rng.choice([6, 8, 8, 10])), 'albedo': albedo,
        'camera': {'fov': round(float(rng.uniform(35, 75)), 2), 'fov_axis': 'x', 'up': [0, 1, 0], 'keyframes': keys},
        'materials': {}, 'shapes': b.shapes, 'emitters': b.emitters,
    }


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--out', required=True, help='directory of the scene files (assets/ beside them)')
    p.add_argument('--split', choices=sorted(SPLITS), default='train')
    p.add_argument('--count', type=int, default=400)
    p.add_argument('--first', type=int, default=0, help='index of the first scene')
    p.add_argument('--seed', type=int, default=1)
    p.add_argument('--width', type=int, default=192)
    p.add_argument('--height', type=int, default=144)
    p.add_argument('--frames', type=int, default=8)
    p.add_argument('--ref-spp', type=int, default=128,
                   help='samples of the target (an unbiased noisy target suffices for training)')
    p.add_argument('--spp', default='',
                   help='comma-separated samples per estimate to draw from (default: 1 in 5 of 9 scenes, else 2-16)')
    a = p.parse_args()
    spp_choices = [int(v) for v in a.spp.split(',') if v.strip()]
    os.makedirs(a.out, exist_ok=True)
    textures, envmaps = make_assets(os.path.join(a.out, 'assets'), a.seed)
    for i in range(a.first, a.first + a.count):
        sc = make_scene(a.split, a.seed, i, textures, envmaps, (a.width, a.height), a.frames, a.ref_spp, spp_choices)
        path = os.path.join(a.out, '%s_%04d.json' % (a.split, i))
        text = json.dumps(sc, indent=1)
        if not os.path.exists(path) or open(path).read() != text:
            with open(path, 'w') as f:
                f.write(text)
    print('%d %s scenes in %s' % (a.count, a.split, a.out))


if __name__ == '__main__':
    main()
