#!/usr/bin/env python3
"""Writes the meshes of the foreign test scenes (torus.obj, vase.obj, chair.obj)
beside this file: shapes the training generator (tools/gen_scenes.py) never
makes. Run by tools/render-foreign.sh; deterministic."""
import math
import os

HERE = os.path.dirname(os.path.abspath(__file__))


def write(name, verts, faces):
    with open(os.path.join(HERE, name), 'w') as f:
        f.write('# written by tools/scenes/foreign/meshes.py\n')
        for v in verts:
            f.write('v %.6f %.6f %.6f\n' % v)
        for a, b, c in faces:
            f.write('f %d %d %d\n' % (a + 1, b + 1, c + 1))


def lathe(profile, segments):
    """Surface of revolution about +y of a (radius, height) polyline."""
    verts, faces = [], []
    for r, y in profile:
        for s in range(segments):
            a = 2 * math.pi * s / segments
            verts.append((r * math.cos(a), y, r * math.sin(a)))
    for i in range(len(profile) - 1):
        for s in range(segments):
            a, b = i * segments + s, i * segments + (s + 1) % segments
            c, d = a + segments, b + segments
            faces += [(a, c, b), (b, c, d)]
    return verts, faces


def torus(big=1.0, small=0.35, nu=64, nv=32):
    verts, faces = [], []
    for i in range(nu):
        u = 2 * math.pi * i / nu
        for j in range(nv):
            v = 2 * math.pi * j / nv
            r = big + small * math.cos(v)
            verts.append((r * math.cos(u), small * math.sin(v), r * math.sin(u)))
    for i in range(nu):
        for j in range(nv):
            a, b = i * nv + j, i * nv + (j + 1) % nv
            c, d = ((i + 1) % nu) * nv + j, ((i + 1) % nu) * nv + (j + 1) % nv
            faces += [(a, b, c), (b, d, c)]
    return verts, faces


def box(x0, y0, z0, x1, y1, z1, base):
    v = [(x, y, z) for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)]
    q = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    f = []
    for a, b, c, d in q:
        f += [(base + a, base + b, base + c), (base + a, base + c, base + d)]
    return v, f


def chair():
    parts = [(-0.22, 0.42, -0.22, 0.22, 0.46, 0.22)]  # seat
    for x in (-0.2, 0.17):
        for z in (-0.2, 0.17):
            parts.append((x, 0.0, z, x + 0.03, 0.42, z + 0.03))  # legs
    parts.append((-0.22, 0.46, -0.22, 0.22, 0.9, -0.19))  # back
    for k in range(4):  # back slats, thin
        x = -0.18 + k * 0.12
        parts.append((x, 0.5, -0.185, x + 0.015, 0.86, -0.17))
    verts, faces = [], []
    for p in parts:
        v, f = box(*p, len(verts))
        verts += v
        faces += f
    return verts, faces


def main():
    write('torus.obj', *torus())
    prof = [(0.001, 0.0), (0.35, 0.0), (0.42, 0.1), (0.45, 0.35), (0.38, 0.6), (0.2, 0.8), (0.16, 1.0), (0.22, 1.1),
            (0.2, 1.1), (0.14, 1.0), (0.18, 0.8), (0.36, 0.6), (0.43, 0.35), (0.4, 0.1), (0.33, 0.02), (0.001, 0.02)]
    write('vase.obj', *lathe(prof, 64))
    write('chair.obj', *chair())


if __name__ == '__main__':
    main()
