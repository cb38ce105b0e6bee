#!/usr/bin/env python3
"""Writes the scene files of the training, validation and held-out test
sequences (tools/scenes/data/*.json) for tools/render.py.

The scenes are generated here (rather than written by hand) so that their
rooms, furniture and lights are easy to vary; run it again after editing:

    python3 tools/make_scenes.py

Each scene is a room or an outdoor set with objects of several materials
(diffuse and textured, rough metal, glossy plastic, glass), HDR area or
point lights, and keyframed motion of the camera, the lights or objects.
"""
import json
import os

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, 'scenes', 'data')


def diffuse(rgb, twosided=True):
    return {'type': 'diffuse', 'twosided': twosided, 'reflectance': rgb}


def checker(c0, c1, scale):
    return {'type': 'diffuse', 'twosided': True,
            'reflectance': {'type': 'checkerboard', 'color0': c0, 'color1': c1,
                            'to_uv': {'scale': [scale, scale]}}}


def metal(name, alpha):
    return {'type': 'roughconductor', 'material': name, 'distribution': 'ggx', 'alpha': alpha}


def plastic(rgb, alpha):
    return {'type': 'roughplastic', 'distribution': 'ggx', 'alpha': alpha,
            'diffuse_reflectance': rgb, 'int_ior': 1.5}


GLASS = {'type': 'dielectric', 'int_ior': 1.5}
BLACK = {'type': 'diffuse', 'reflectance': [0.0, 0.0, 0.0]}


def room(w=4.0, d=4.0, h=3.0, floor=None, walls=(0.7, 0.68, 0.62), side=(0.5, 0.55, 0.65), ceiling=True):
    """Floor, back wall, left and right walls (open towards +z, the camera)."""
    s = [
        {'id': 'floor', 'type': 'rectangle', 'material': floor or checker([0.7, 0.68, 0.64], [0.18, 0.17, 0.16], 12),
         'transform': {'scale': [w, d, 1], 'rotate': [1, 0, 0, -90]}},
        {'id': 'back', 'type': 'rectangle', 'material': diffuse(list(walls)),
         'transform': {'scale': [w, h / 2, 1], 'translate': [0, h / 2, -d]}},
        {'id': 'left', 'type': 'rectangle', 'material': diffuse(list(side)),
         'transform': {'scale': [d, h / 2, 1], 'rotate': [0, 1, 0, 90], 'translate': [-w, h / 2, 0]}},
        {'id': 'right', 'type': 'rectangle', 'material': diffuse(list(walls)),
         'transform': {'scale': [d, h / 2, 1], 'rotate': [0, 1, 0, -90], 'translate': [w, h / 2, 0]}},
    ]
    if ceiling:
        s.append({'id': 'ceiling', 'type': 'rectangle', 'material': diffuse([0.8, 0.8, 0.8]),
                  'transform': {'scale': [w, d, 1], 'rotate': [1, 0, 0, 90], 'translate': [0, h, 0]}})
    return s


def area(id_, radiance, scale, translate, rotate=(1, 0, 0, 90), keys=None):
    s = {'id': id_, 'type': 'rectangle', 'emitter': {'type': 'area', 'radiance': radiance},
         'material': BLACK, 'transform': {'scale': scale, 'rotate': list(rotate), 'translate': translate}}
    if keys:
        s['keyframes'] = keys
    return s


def sphere_light(id_, radiance, r, at, keys=None):
    s = {'id': id_, 'type': 'sphere', 'emitter': {'type': 'area', 'radiance': radiance},
         'material': BLACK, 'transform': {'scale': r, 'translate': at}}
    if keys:
        s['keyframes'] = keys
    return s


def obj(id_, kind, mat, scale, translate, rotate=None, keys=None):
    t = {'scale': scale, 'translate': translate}
    if rotate:
        t['rotate'] = rotate
    s = {'id': id_, 'type': kind, 'material': mat, 'transform': t}
    if keys:
        s['keyframes'] = keys
    return s


def cam(keys, fov=55):
    return {'fov': fov, 'fov_axis': 'x', 'up': [0, 1, 0], 'keyframes': keys}


def scene(desc, camera, shapes, emitters=(), frames=12, seed=1, ref_spp=1024):
    return {'description': desc, 'resolution': [256, 144], 'frames': frames, 'spp': 1, 'ref_spp': ref_spp,
            'aov_spp': 32, 'seed': seed, 'max_depth': 8, 'camera': camera, 'shapes': shapes,
            'emitters': list(emitters)}


def furniture(prefix, x=0.0, z=-1.0, col=(0.6, 0.3, 0.2)):
    """A table (top and four legs) and a box on it."""
    top = obj(prefix + '_top', 'cube', diffuse(list(col)), [0.9, 0.05, 0.5], [x, 0.8, z])
    legs = [obj('%s_leg%d' % (prefix, i), 'cylinder', diffuse([0.2, 0.2, 0.22]), [0.04, 0.04, 0.8],
                [x + dx, 0.0, z + dz], rotate=[1, 0, 0, -90])
            for i, (dx, dz) in enumerate([(-0.8, -0.4), (0.8, -0.4), (-0.8, 0.4), (0.8, 0.4)])]
    return [top] + legs


SCENES = {}

# --- training ---------------------------------------------------------------
SCENES['train_livingroom'] = scene(
    'living room: checker floor, a sofa of boxes, a gold sphere, a glossy blue ball, ceiling light; camera pans left to right',
    cam([{'t': 0, 'origin': [-1.6, 1.5, 3.8], 'target': [-0.4, 0.8, -1.0]},
         {'t': 1, 'origin': [1.6, 1.5, 3.8], 'target': [0.6, 0.8, -1.0]}]),
    room() + [
        obj('sofa', 'cube', diffuse([0.35, 0.12, 0.1]), [1.2, 0.35, 0.45], [-1.2, 0.35, -2.8]),
        obj('sofa_back', 'cube', diffuse([0.35, 0.12, 0.1]), [1.2, 0.4, 0.12], [-1.2, 0.8, -3.25]),
        obj('gold', 'sphere', metal('Au', 0.15), 0.45, [1.0, 0.45, -1.5]),
        obj('ball', 'sphere', plastic([0.05, 0.15, 0.6], 0.08), 0.3, [0.1, 0.3, -0.5]),
        area('light', [14, 12.5, 11], [0.8, 0.5, 1], [0, 2.98, -1.2]),
    ] + furniture('t1', x=1.9, z=-2.8, col=(0.55, 0.4, 0.25)), seed=101)

SCENES['train_kitchen'] = scene(
    'kitchen: counters, copper and aluminium bowls, a small very bright light (fireflies through the metal); camera dollies in',
    cam([{'t': 0, 'origin': [0.3, 1.7, 4.2], 'target': [0.0, 0.9, -1.5]},
         {'t': 1, 'origin': [0.1, 1.5, 2.2], 'target': [0.2, 0.9, -1.8]}], fov=60),
    room(floor=checker([0.85, 0.85, 0.85], [0.1, 0.1, 0.12], 20), walls=(0.85, 0.82, 0.75), side=(0.7, 0.78, 0.7)) + [
        obj('counter', 'cube', diffuse([0.9, 0.9, 0.88]), [2.5, 0.45, 0.5], [0, 0.45, -3.4]),
        obj('copper', 'sphere', metal('Cu', 0.08), 0.3, [-0.8, 1.2, -3.3]),
        obj('alu', 'sphere', metal('Al', 0.25), 0.25, [0.6, 1.15, -3.2]),
        obj('stool', 'cylinder', plastic([0.7, 0.1, 0.1], 0.2), [0.25, 0.25, 0.6], [0.9, 0.0, -1.6], rotate=[1, 0, 0, -90]),
        sphere_light('bulb', [400, 360, 300], 0.05, [0.3, 2.3, -2.6]),
        area('window', [3, 3.5, 4.5], [0.6, 0.8, 1], [-3.98, 1.6, -1.5], rotate=[0, 1, 0, 90]),
    ], seed=102)

SCENES['train_hallway'] = scene(
    'hallway: pillars, a row of small ceiling lights, a glossy floor; camera walks down the hall',
    cam([{'t': 0, 'origin': [0.0, 1.6, 3.5], 'target': [0.0, 1.2, -3.0]},
         {'t': 1, 'origin': [0.4, 1.6, 0.5], 'target': [-0.3, 1.2, -4.0]}], fov=65),
    room(w=1.8, d=5.0, floor=plastic([0.25, 0.2, 0.15], 0.05), walls=(0.75, 0.7, 0.6), side=(0.6, 0.6, 0.55)) + [
        obj('pillar%d' % i, 'cylinder', diffuse([0.8, 0.8, 0.78]), [0.15, 0.15, 3.0], [sx * 1.4, 0.0, z], rotate=[1, 0, 0, -90])
        for i, (sx, z) in enumerate([(-1, -1.0), (1, -1.0), (-1, -3.0), (1, -3.0)])
    ] + [area('lamp%d' % i, [30, 26, 20], [0.2, 0.2, 1], [0, 2.98, z]) for i, z in enumerate([1.0, -1.0, -3.0])]
    + [obj('bench', 'cube', diffuse([0.4, 0.25, 0.12]), [0.25, 0.25, 0.8], [1.3, 0.25, -2.0])], seed=103)

SCENES['train_outdoor'] = scene(
    'outdoor: a courtyard under a bright sky and sun, boxes and spheres casting hard shadows; camera orbits',
    cam([{'t': 0, 'origin': [-3.5, 2.0, 3.5], 'target': [0, 0.5, 0]},
         {'t': 0.5, 'origin': [0.0, 2.3, 4.8], 'target': [0, 0.5, 0]},
         {'t': 1, 'origin': [3.5, 2.0, 3.5], 'target': [0, 0.5, 0]}], fov=60),
    [obj('ground', 'rectangle', checker([0.55, 0.5, 0.4], [0.3, 0.32, 0.25], 10), [8, 8, 1], [0, 0, 0], rotate=[1, 0, 0, -90]),
     obj('box1', 'cube', diffuse([0.7, 0.3, 0.2]), 0.5, [-1.0, 0.5, -0.5], rotate=[0, 1, 0, 25]),
     obj('box2', 'cube', diffuse([0.2, 0.5, 0.7]), [0.3, 0.8, 0.3], [1.2, 0.8, -1.0]),
     obj('ball', 'sphere', plastic([0.9, 0.8, 0.1], 0.1), 0.45, [0.4, 0.45, 0.8]),
     obj('steel', 'sphere', metal('Cr', 0.05), 0.35, [-1.5, 0.35, 1.2])],
    emitters=[{'type': 'constant', 'radiance': [0.9, 1.05, 1.3]},
              {'type': 'directional', 'irradiance': [6, 5.6, 5], 'direction': [-0.4, -1.0, -0.5]}], seed=104)

SCENES['train_glass'] = scene(
    'glass on a table: a glass sphere and cube with caustics, an area light sliding across; fixed camera',
    cam([{'t': 0, 'origin': [0.0, 1.6, 2.6], 'target': [0.0, 0.85, -1.0]},
         {'t': 1, 'origin': [0.0, 1.6, 2.6], 'target': [0.0, 0.85, -1.0]}]),
    room(floor=diffuse([0.5, 0.45, 0.4]), walls=(0.6, 0.62, 0.7)) + furniture('t', x=0.0, z=-1.0, col=(0.8, 0.78, 0.72)) + [
        obj('gsphere', 'sphere', GLASS, 0.22, [-0.35, 1.07, -1.0]),
        obj('gcube', 'cube', GLASS, 0.15, [0.35, 1.0, -0.9], rotate=[0, 1, 0, 30]),
        area('slide', [22, 20, 18], [0.4, 0.4, 1], [-1.5, 2.95, -0.8], keys=[{'t': 0, 'translate': [-1.8, 2.95, -0.8]},
                                                                        {'t': 1, 'translate': [1.8, 2.95, -1.2]}]),
    ], seed=105)

SCENES['train_dim'] = scene(
    'a dim bedroom: one small lamp and a faint window; low radiance everywhere; camera pans slowly',
    cam([{'t': 0, 'origin': [-0.8, 1.4, 3.5], 'target': [-0.2, 0.8, -1.5]},
         {'t': 1, 'origin': [0.8, 1.3, 3.3], 'target': [0.4, 0.8, -1.5]}]),
    room(walls=(0.5, 0.45, 0.4), side=(0.35, 0.4, 0.5)) + [
        obj('bed', 'cube', diffuse([0.7, 0.7, 0.75]), [1.0, 0.3, 1.2], [-1.6, 0.3, -2.6]),
        obj('pillow', 'cube', diffuse([0.9, 0.9, 0.85]), [0.5, 0.1, 0.25], [-1.6, 0.7, -3.5]),
        obj('nightstand', 'cube', diffuse([0.4, 0.25, 0.15]), 0.3, [0.0, 0.3, -3.5]),
        sphere_light('lamp', [25, 18, 9], 0.08, [0.0, 0.75, -3.5]),
        area('window', [0.15, 0.18, 0.3], [0.5, 0.7, 1], [3.98, 1.6, -2.0], rotate=[0, 1, 0, -90]),
        obj('vase', 'cylinder', plastic([0.1, 0.4, 0.3], 0.1), [0.12, 0.12, 0.35], [1.2, 0.0, -3.0], rotate=[1, 0, 0, -90]),
    ], seed=106)

SCENES['train_spotlight'] = scene(
    'a stage: a spot light swings across statues of boxes and spheres; fixed camera, shadows sweep',
    cam([{'t': 0, 'origin': [0.0, 1.8, 4.0], 'target': [0.0, 0.7, -1.0]},
         {'t': 1, 'origin': [0.0, 1.8, 4.0], 'target': [0.0, 0.7, -1.0]}]),
    room(floor=diffuse([0.6, 0.6, 0.6]), walls=(0.7, 0.7, 0.7), ceiling=False) + [
        obj('s1', 'cube', diffuse([0.8, 0.2, 0.2]), [0.3, 0.6, 0.3], [-1.2, 0.6, -1.5]),
        obj('s2', 'sphere', metal('Ag', 0.2), 0.4, [0.0, 0.4, -1.2]),
        obj('s3', 'cylinder', plastic([0.2, 0.7, 0.3], 0.15), [0.25, 0.25, 1.2], [1.2, 0.0, -1.8], rotate=[1, 0, 0, -90]),
    ],
    emitters=[{'type': 'spot', 'intensity': [60, 55, 50], 'cutoff_angle': 30,
               'keyframes': [{'t': 0, 'origin': [-3.0, 3.0, 1.0], 'target': [0.5, 0.0, -1.5]},
                             {'t': 1, 'origin': [3.0, 3.0, 1.0], 'target': [-0.5, 0.0, -1.5]}]},
              {'type': 'constant', 'radiance': [0.05, 0.05, 0.06]}], seed=107)

SCENES['train_toys'] = scene(
    'toys: balls roll and a box slides across a rug under two area lights; camera drifts',
    cam([{'t': 0, 'origin': [-0.5, 1.3, 3.0], 'target': [0.0, 0.3, -0.5]},
         {'t': 1, 'origin': [0.5, 1.4, 2.8], 'target': [0.1, 0.3, -0.7]}], fov=60),
    room(floor=checker([0.6, 0.2, 0.2], [0.9, 0.85, 0.7], 24), walls=(0.75, 0.75, 0.8)) + [
        obj('ball1', 'sphere', plastic([0.9, 0.4, 0.05], 0.1), 0.2, [-1.0, 0.2, -0.5],
            keys=[{'t': 0, 'translate': [-1.2, 0.2, -0.4]}, {'t': 1, 'translate': [0.6, 0.2, -0.2]}]),
        obj('ball2', 'sphere', metal('Au', 0.3), 0.18, [0.8, 0.18, -1.0],
            keys=[{'t': 0, 'translate': [1.0, 0.18, -1.4]}, {'t': 1, 'translate': [-0.4, 0.18, -0.6]}]),
        obj('crate', 'cube', diffuse([0.3, 0.6, 0.9]), 0.22, [0.0, 0.22, -1.6],
            keys=[{'t': 0, 'translate': [-0.8, 0.22, -1.8]}, {'t': 1, 'translate': [0.9, 0.22, -1.5]}]),
        area('l1', [9, 9, 10], [0.6, 0.6, 1], [-1.0, 2.98, -0.5]),
        area('l2', [10, 8, 6], [0.4, 0.4, 1], [1.5, 2.98, -2.0]),
    ], seed=108)

# --- validation -------------------------------------------------------------
SCENES['val_study'] = scene(
    'a study: bookshelf of boxes, a plastic globe, a desk lamp; camera pans',
    cam([{'t': 0, 'origin': [-1.0, 1.5, 3.2], 'target': [0.0, 1.0, -1.5]},
         {'t': 1, 'origin': [1.0, 1.5, 3.2], 'target': [0.2, 1.0, -1.5]}]),
    room(walls=(0.65, 0.7, 0.6), side=(0.55, 0.45, 0.4)) + furniture('d', x=0.5, z=-2.0, col=(0.45, 0.3, 0.2)) + [
        obj('shelf%d' % i, 'cube', diffuse([0.2 + 0.15 * i, 0.3, 0.5 - 0.1 * i]), [0.2, 0.3, 0.15], [-1.8 + 0.45 * i, 0.3 + 0.6 * (i % 2), -3.7])
        for i in range(5)
    ] + [obj('globe', 'sphere', plastic([0.1, 0.3, 0.7], 0.05), 0.2, [0.7, 1.05, -2.0]),
         sphere_light('desklamp', [60, 50, 35], 0.05, [0.0, 1.3, -2.1]),
         area('ceil', [4, 4, 4.4], [0.6, 0.6, 1], [0, 2.98, 0.0])],
    frames=8, seed=201)

# --- held-out tests ---------------------------------------------------------
SCENES['heldout_pan'] = scene(
    'held-out: a furnished lounge (armchairs, a chrome lamp, a rug, a plant pot), ceiling and window light; the camera pans',
    cam([{'t': 0, 'origin': [-2.0, 1.6, 3.6], 'target': [-0.6, 0.9, -1.2]},
         {'t': 1, 'origin': [2.0, 1.6, 3.6], 'target': [0.8, 0.9, -1.2]}]),
    room(floor=checker([0.5, 0.35, 0.25], [0.3, 0.2, 0.12], 16), walls=(0.8, 0.75, 0.65), side=(0.4, 0.5, 0.45)) + [
        obj('chair1', 'cube', diffuse([0.15, 0.3, 0.2]), [0.5, 0.3, 0.5], [-1.7, 0.3, -2.4]),
        obj('chair1b', 'cube', diffuse([0.15, 0.3, 0.2]), [0.5, 0.5, 0.1], [-1.7, 0.8, -2.85]),
        obj('chair2', 'cube', diffuse([0.5, 0.15, 0.15]), [0.5, 0.3, 0.5], [1.6, 0.3, -2.6]),
        obj('rug', 'rectangle', checker([0.7, 0.6, 0.3], [0.2, 0.3, 0.5], 6), [1.2, 0.8, 1], [0, 0.005, -1.6], rotate=[1, 0, 0, -90]),
        obj('lampstand', 'cylinder', metal('Cr', 0.05), [0.03, 0.03, 1.5], [0.2, 0.0, -3.2], rotate=[1, 0, 0, -90]),
        sphere_light('lampbulb', [35, 30, 22], 0.12, [0.2, 1.6, -3.2]),
        obj('pot', 'cylinder', plastic([0.6, 0.3, 0.15], 0.2), [0.25, 0.25, 0.4], [2.5, 0.0, -1.0], rotate=[1, 0, 0, -90]),
        obj('plant', 'sphere', diffuse([0.1, 0.45, 0.1]), 0.35, [2.5, 0.75, -1.0]),
        obj('mirrorball', 'sphere', metal('Ag', 0.02), 0.25, [-0.5, 0.25, -0.8]),
        area('ceil', [10, 9.5, 8.5], [1.0, 0.7, 1], [0, 2.98, -1.5]),
        area('window', [2.5, 3.0, 4.0], [1.0, 0.8, 1], [-3.98, 1.7, -1.0], rotate=[0, 1, 0, 90]),
    ], frames=24, seed=301, ref_spp=2048)

SCENES['heldout_light'] = scene(
    'held-out: fixed camera on a table with a teapot-like group (sphere, cylinder, box); one area light moves across the room, shadows sweep',
    cam([{'t': 0, 'origin': [0.3, 1.7, 3.0], 'target': [0.0, 0.8, -1.2]},
         {'t': 1, 'origin': [0.3, 1.7, 3.0], 'target': [0.0, 0.8, -1.2]}]),
    room(floor=diffuse([0.55, 0.55, 0.5]), walls=(0.75, 0.72, 0.68), side=(0.55, 0.6, 0.7)) + furniture('t', x=0.0, z=-1.2, col=(0.5, 0.35, 0.25)) + [
        obj('pot', 'sphere', plastic([0.8, 0.8, 0.75], 0.1), 0.2, [-0.3, 1.05, -1.2]),
        obj('cup', 'cylinder', metal('Cu', 0.15), [0.08, 0.08, 0.18], [0.25, 0.85, -1.0], rotate=[1, 0, 0, -90]),
        obj('box', 'cube', diffuse([0.2, 0.35, 0.7]), 0.12, [0.45, 0.97, -1.45], rotate=[0, 1, 0, 20]),
        obj('chair', 'cube', diffuse([0.3, 0.2, 0.12]), [0.3, 0.45, 0.3], [-1.6, 0.45, -1.8]),
        area('moving', [24, 21, 17], [0.35, 0.35, 1], [-2.0, 2.9, -0.5],
             keys=[{'t': 0, 'translate': [-2.5, 2.9, 0.2]}, {'t': 0.5, 'translate': [0.0, 2.9, -2.5]},
                   {'t': 1, 'translate': [2.5, 2.9, 0.2]}]),
    ], emitters=[{'type': 'constant', 'radiance': [0.02, 0.02, 0.025]}], frames=24, seed=302, ref_spp=2048)

SCENES['heldout_object'] = scene(
    'held-out: a ball rolls across a checker floor past a glass box and a gold cylinder while the camera follows',
    cam([{'t': 0, 'origin': [-1.2, 1.2, 2.8], 'target': [-0.8, 0.3, -0.5]},
         {'t': 1, 'origin': [1.2, 1.2, 2.8], 'target': [0.8, 0.3, -0.5]}], fov=60),
    room(floor=checker([0.8, 0.8, 0.8], [0.25, 0.25, 0.3], 18), walls=(0.7, 0.65, 0.6)) + [
        obj('ball', 'sphere', plastic([0.1, 0.6, 0.2], 0.08), 0.22, [0.0, 0.22, -0.3],
            keys=[{'t': 0, 'translate': [-1.5, 0.22, -0.2]}, {'t': 1, 'translate': [1.5, 0.22, -0.6]}]),
        obj('gbox', 'cube', GLASS, 0.25, [-0.3, 0.25, -1.5]),
        obj('gold', 'cylinder', metal('Au', 0.1), [0.2, 0.2, 0.7], [0.9, 0.0, -1.8], rotate=[1, 0, 0, -90]),
        area('ceil', [12, 11, 10], [0.8, 0.6, 1], [0, 2.98, -1.0]),
    ], frames=24, seed=303, ref_spp=2048)


# --- the test corpus (tests/fixtures/corpus, small enough to check in) -------
# Rendered by tools/render-corpus.sh at 128x128 or 160x96; each frame carries
# the second estimate B.*, and the tests also drop it to get the
# single-estimate case.
CORPUS = {}


def small(sc, res, frames, ref_spp, aov_spp=64):
    sc = dict(sc)
    sc.update({'resolution': list(res), 'frames': frames, 'ref_spp': ref_spp, 'aov_spp': aov_spp})
    return sc


def cornell_box():
    """A Cornell box written out: white floor, ceiling and back, red left and
    green right walls, a ceiling light, a tall block and a ball."""
    white, red, green = diffuse([0.73, 0.73, 0.73]), diffuse([0.63, 0.065, 0.05]), diffuse([0.14, 0.45, 0.091])
    return [
        obj('floor', 'rectangle', white, [1, 1, 1], [0, -1, 0], rotate=[1, 0, 0, -90]),
        obj('ceiling', 'rectangle', white, [1, 1, 1], [0, 1, 0], rotate=[1, 0, 0, 90]),
        obj('back', 'rectangle', white, [1, 1, 1], [0, 0, -1]),
        obj('left', 'rectangle', red, [1, 1, 1], [-1, 0, 0], rotate=[0, 1, 0, 90]),
        obj('right', 'rectangle', green, [1, 1, 1], [1, 0, 0], rotate=[0, 1, 0, -90]),
        obj('block', 'cube', white, [0.28, 0.6, 0.28], [-0.35, -0.4, -0.4], rotate=[0, 1, 0, 18]),
        obj('ball', 'sphere', white, 0.3, [0.4, -0.7, 0.2]),
        area('light', [17, 12, 4], [0.23, 0.19, 1], [0, 0.995, 0]),
    ]


CORPUS['corpus_cornell'] = {
    'description': "corpus: Mitsuba's built-in Cornell box (mi.cornell_box()), 256x256, box filter, static; rendered at 4, 16 and 64 spp",
    'builtin': 'cornell_box', 'resolution': [256, 256], 'frames': 1, 'spp': 16, 'ref_spp': 4096, 'aov_spp': 64,
    'seed': 405, 'max_depth': 8}

CORPUS['corpus_box'] = small(scene(
    'corpus: a Cornell box written out (red and green walls, a block and a ball, a ceiling light whose own albedo is 0), static; rendered at 4, 16 and 64 spp',
    cam([{'t': 0, 'origin': [0, 0, 3.9], 'target': [0, 0, 0]}], fov=39.3),
    cornell_box(), seed=401), (128, 128), 1, 8192)

CORPUS['corpus_glossy'] = small(scene(
    'corpus: a room of glossy materials (polished plastic floor, rough and smooth metals, a glossy wall), ceiling light; the camera pans and dollies',
    cam([{'t': 0, 'origin': [-0.9, 1.5, 3.2], 'target': [-0.2, 0.7, -1.5]},
         {'t': 1, 'origin': [0.5, 1.3, 2.6], 'target': [0.4, 0.7, -1.5]}], fov=60),
    room(floor=plastic([0.35, 0.3, 0.25], 0.05), walls=(0.75, 0.72, 0.68)) + [
        obj('glosswall', 'rectangle', plastic([0.2, 0.35, 0.55], 0.12), [1.2, 0.9, 1], [1.2, 1.2, -3.98]),
        obj('chrome', 'sphere', metal('Cr', 0.02), 0.4, [-0.9, 0.4, -1.8]),
        obj('brass', 'sphere', metal('Au', 0.2), 0.3, [0.5, 0.3, -1.0]),
        obj('redball', 'sphere', plastic([0.6, 0.08, 0.05], 0.04), 0.25, [1.3, 0.25, -2.0]),
        obj('plinth', 'cube', plastic([0.9, 0.9, 0.85], 0.3), [0.3, 0.35, 0.3], [-0.1, 0.35, -2.6]),
        area('light', [10, 9.5, 9], [0.9, 0.6, 1], [0, 2.98, -1.5]),
    ], seed=402), (160, 96), 3, 4096)

CORPUS['corpus_hdr'] = small(scene(
    'corpus: high dynamic range: a visible bulb of radiance 1000, a dark alcove near 1e-3, rough metals whose Mitsuba albedo AOV '
    'exceeds 1 (rendered with --albedo mitsuba), a glass ball and a polished floor that make fireflies; the bulb moves',
    cam([{'t': 0, 'origin': [0.0, 1.3, 3.0], 'target': [0.0, 0.9, -1.5]}], fov=62),
    room(floor=plastic([0.2, 0.2, 0.22], 0.02), walls=(0.8, 0.8, 0.78), side=(0.01, 0.01, 0.01)) + [
        obj('copper', 'sphere', metal('Cu', 0.15), 0.35, [-0.8, 0.35, -1.6]),
        obj('alu', 'cylinder', metal('Al', 0.3), [0.25, 0.25, 0.9], [0.9, 0.0, -2.0], rotate=[1, 0, 0, -90]),
        obj('glass', 'sphere', GLASS, 0.3, [0.1, 0.3, -0.8]),
        obj('alcove', 'cube', diffuse([0.6, 0.6, 0.6]), [0.5, 0.6, 0.02], [-2.4, 0.6, -3.2]),
        sphere_light('bulb', [1000, 900, 750], 0.04, [0.2, 1.9, -2.2],
                     keys=[{'t': 0, 'translate': [-0.3, 1.9, -2.2]}, {'t': 1, 'translate': [0.5, 1.8, -2.0]}]),
    ], seed=403), (160, 96), 2, 4096)

CORPUS['corpus_dim'] = small(scene(
    'corpus: a dim room lit only through a narrow door slit from a lamp outside (radiance about 1e-3..1e-1 inside), a little light moves',
    cam([{'t': 0, 'origin': [1.5, 1.4, 3.2], 'target': [-0.5, 0.8, -1.5]}], fov=60),
    [w for w in room(walls=(0.6, 0.55, 0.5)) if w['id'] != 'left'] + [
        obj('door_l', 'cube', diffuse([0.5, 0.5, 0.5]), [0.02, 1.5, 1.8], [-3.98, 1.5, -2.1]),
        obj('door_r', 'cube', diffuse([0.5, 0.5, 0.5]), [0.02, 1.5, 1.8], [-3.98, 1.5, 1.9]),
        area('outside', [5, 4.3, 3.5], [1.0, 1.5, 1], [-4.6, 1.5, -0.2], rotate=[0, 1, 0, 90]),
        obj('chair', 'cube', diffuse([0.5, 0.3, 0.2]), [0.4, 0.4, 0.4], [-1.0, 0.4, -1.5]),
        obj('vase', 'sphere', plastic([0.2, 0.4, 0.3], 0.1), 0.3, [0.8, 0.3, -2.4]),
        sphere_light('ember', [0.8, 0.4, 0.1], 0.05, [0.0, 0.3, -0.5],
                     keys=[{'t': 0, 'translate': [-0.2, 0.3, -0.5]}, {'t': 1, 'translate': [0.2, 0.3, -0.5]}]),
    ], seed=404), (160, 96), 2, 4096)

CORPUS['corpus_metals'] = dict(small(scene(
    "corpus: what a renderer's raw albedo AOV makes of materials without a diffuse reflectance (rendered with "
    "--albedo mitsuba): rough gold, smooth silver, rough copper and aluminium, glass; near-black paint (albedo "
    "0.001, 0.004 and 0.01) beside white; a dark checker floor (0.02 / 0.05); a visible bulb and a ceiling light; "
    "the camera drifts",
    cam([{'t': 0, 'origin': [-0.3, 1.2, 2.6], 'target': [0.0, 0.7, -1.5]},
         {'t': 1, 'origin': [0.1, 1.25, 2.5], 'target': [0.15, 0.7, -1.5]}], fov=62),
    room(floor=checker([0.02, 0.02, 0.02], [0.05, 0.045, 0.04], 10), walls=(0.8, 0.8, 0.78)) + [
        obj('paint1', 'rectangle', diffuse([0.001, 0.001, 0.001]), [0.3, 0.4, 1], [-1.5, 1.5, -3.99]),
        obj('paint2', 'rectangle', diffuse([0.004, 0.004, 0.004]), [0.3, 0.4, 1], [-0.7, 1.5, -3.99]),
        obj('paint3', 'rectangle', diffuse([0.01, 0.009, 0.008]), [0.3, 0.4, 1], [0.1, 1.5, -3.99]),
        obj('white', 'rectangle', diffuse([0.92, 0.92, 0.9]), [0.3, 0.4, 1], [0.9, 1.5, -3.99]),
        obj('gold', 'sphere', metal('Au', 0.1), 0.32, [-1.1, 0.32, -1.6]),
        obj('silver', 'sphere', {'type': 'conductor', 'material': 'Ag'}, 0.28, [-0.35, 0.28, -1.0]),
        obj('copper', 'cube', metal('Cu', 0.3), [0.22, 0.22, 0.22], [0.45, 0.22, -1.7], rotate=[0, 1, 0, 30]),
        obj('alu', 'cylinder', metal('Al', 0.2), [0.15, 0.15, 0.7], [1.15, 0.0, -1.2], rotate=[1, 0, 0, -90]),
        obj('glass', 'sphere', GLASS, 0.22, [0.25, 0.22, -0.5]),
        sphere_light('bulb', [300, 270, 220], 0.05, [-0.2, 1.7, -2.0]),
        area('light', [8, 7.6, 7], [0.8, 0.5, 1], [0, 2.98, -1.2]),
    ], seed=406), (160, 96), 2, 4096), albedo='mitsuba')


def main():
    os.makedirs(OUT, exist_ok=True)
    for name, sc in SCENES.items():
        with open(os.path.join(OUT, name + '.json'), 'w') as f:
            json.dump(sc, f, indent=1)
    print('wrote %d scenes to %s' % (len(SCENES), OUT))
    corpus = os.path.join(HERE, 'scenes', 'corpus')
    os.makedirs(corpus, exist_ok=True)
    for name, sc in CORPUS.items():
        with open(os.path.join(corpus, name + '.json'), 'w') as f:
            json.dump(sc, f, indent=1)
    print('wrote %d scenes to %s' % (len(CORPUS), corpus))


if __name__ == '__main__':
    main()
