#!/usr/bin/env python3
"""Render frame sequences for mcdenoise with Mitsuba 3.

A scene is described by a JSON file (see tools/README.md and tools/scenes/).
For every frame t the script writes

  <out>/frame_NNNN.exr      R,G,B            noisy radiance (--spp, default 1)
                            B.R,B.G,B.B      independent second estimate (other seed)
                            albedo.R,G,B     Mitsuba `albedo` AOV
                            normal.X,Y,Z     world-space shading normal (`sh_normal`)
                            depth.Z          distance along the camera ray (`depth`), 0 = miss
                            position.X,Y,Z   world-space position (`position`), 0 = miss
                            motion.X,Y       pixels; previous = current + motion
  <out>/ref/frame_NNNN.exr  R,G,B            high-spp reference (--ref-spp)
  <out>/render_info.json    parameters, seeds, cameras, timings, checks

Pixel convention: pixel (x, y) covers [x, x+1) x [y, y+1) in film coordinates,
its centre is (x + 0.5, y + 0.5), x grows to the right, y grows DOWN (row 0 is
the top row of the image). The motion of a pixel is measured at its centre:
the surface point seen through the pixel centre at frame t is projected with
the camera (and the object transform) of frame t-1, giving the continuous
position q; motion = q - (x + 0.5, y + 0.5). Frame 0 has motion 0.

Run `render.py --help` for the options. Randomness is fully determined by the
scene's seed (or --seed): every render call uses a seed derived from
(seed, frame, stream, pass) by a hash, see `derive_seed`.
"""

import argparse
import glob
import hashlib
import json
import math
import os
import sys
import time

import numpy as np

# -----------------------------------------------------------------------------
# Mitsuba start-up
# -----------------------------------------------------------------------------

LLVM_CANDIDATES = [
    '/usr/lib/x86_64-linux-gnu/libLLVM-19.so',
    '/usr/lib/aarch64-linux-gnu/libLLVM-19.so',
    '/usr/lib/llvm-19/lib/libLLVM.so',
    '/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1',
]

mi = None  # set by init_mitsuba()
dr = None


def find_libllvm():
    """Path of a libLLVM usable by Dr.Jit, or None."""
    env = os.environ.get('DRJIT_LIBLLVM_PATH')
    if env and os.path.isfile(env):
        return env
    for cand in LLVM_CANDIDATES:
        if os.path.isfile(cand):
            return cand
    found = sorted(glob.glob('/usr/lib/*/libLLVM-1[5-9].so') + glob.glob('/usr/lib/*/libLLVM-2?.so'))
    return found[-1] if found else None


def init_mitsuba(variant=None):
    """Import Mitsuba and select a variant; falls back to scalar_rgb without libLLVM."""
    global mi, dr
    want = variant or os.environ.get('MCDENOISE_MI_VARIANT') or 'llvm_ad_rgb'
    if want.startswith('llvm'):
        lib = find_libllvm()
        if lib is None:
            print('render.py: no libLLVM found (run tools/setup-render.sh); '
                  'falling back to scalar_rgb, which is much slower', file=sys.stderr)
            want = 'scalar_rgb'
        else:
            os.environ['DRJIT_LIBLLVM_PATH'] = lib
    import mitsuba
    import drjit
    mi, dr = mitsuba, drjit
    try:
        mi.set_variant(want)
    except Exception as exc:  # LLVM present but unusable
        if want == 'scalar_rgb':
            raise
        print('render.py: variant %s unavailable (%s); using scalar_rgb' % (want, exc),
              file=sys.stderr)
        want = 'scalar_rgb'
        mi.set_variant(want)
    return want


def is_jit():
    return not mi.variant().startswith('scalar')


# -----------------------------------------------------------------------------
# Small maths helpers (numpy, float64)
# -----------------------------------------------------------------------------

def vec3(v, what='vector'):
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.size == 1:
        a = np.repeat(a, 3)
    if a.size != 3:
        raise ValueError('%s must have 3 components, got %r' % (what, v))
    return a


def normalize(v):
    n = np.linalg.norm(v)
    if n == 0:
        raise ValueError('cannot normalize a zero vector')
    return v / n


def look_at(origin, target, up):
    """Camera-to-world matrix in Mitsuba's convention.

    Local +Z looks at the target, local +Y is up and local +X points to the
    camera's left, which Mitsuba's perspective sensor maps to the left edge
    (x = 0) of the image.
    """
    origin, target, up = vec3(origin), vec3(target), vec3(up)
    fwd = normalize(target - origin)
    left = np.cross(up, fwd)
    if np.linalg.norm(left) < 1e-9:
        raise ValueError('camera up vector is parallel to the viewing direction')
    left = normalize(left)
    new_up = np.cross(fwd, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, fwd, origin
    return m


def rotation(axis, degrees):
    """4x4 right-handed rotation by `degrees` about `axis`."""
    k = normalize(vec3(axis, 'rotation axis'))
    a = math.radians(degrees)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    r = np.eye(3) + math.sin(a) * kx + (1 - math.cos(a)) * (kx @ kx)
    m = np.eye(4)
    m[:3, :3] = r
    return m


def transform_matrix(spec):
    """to_world from {"scale", "rotate", "translate"}: M = T * R_n..R_1 * S.

    scale: number or [sx, sy, sz]; rotate: [ax, ay, az, degrees] or a list of
    them (applied in order); translate: [x, y, z]. A 4x4 "matrix" (row-major
    nested list) may be given instead and is then used as is.
    """
    if spec is None:
        return np.eye(4)
    if 'matrix' in spec:
        m = np.asarray(spec['matrix'], dtype=np.float64)
        if m.shape != (4, 4):
            raise ValueError('transform matrix must be 4x4')
        return m
    m = np.eye(4)
    if 'scale' in spec:
        s = vec3(spec['scale'], 'scale')
        m = np.diag([s[0], s[1], s[2], 1.0]) @ m
    rot = spec.get('rotate')
    if rot is not None and len(rot) > 0:
        rots = [rot] if not isinstance(rot[0], (list, tuple)) else rot
        for r in rots:
            if len(r) != 4:
                raise ValueError('rotate entries are [ax, ay, az, degrees], got %r' % (r,))
            m = rotation(r[:3], r[3]) @ m
    if 'translate' in spec:
        t = np.eye(4)
        t[:3, 3] = vec3(spec['translate'], 'translate')
        m = t @ m
    return m


def lerp_value(a, b, w):
    if isinstance(a, (int, float)) and isinstance(b, (int, float)):
        return (1.0 - w) * a + w * b
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        if len(a) != len(b):
            raise ValueError('keyframe values of different lengths: %r / %r' % (a, b))
        return [lerp_value(x, y, w) for x, y in zip(a, b)]
    if isinstance(a, dict) and isinstance(b, dict):
        return {k: (lerp_value(a[k], b[k], w) if k in b else a[k]) for k in a}
    return a if w < 0.5 else b  # strings, booleans: step


def keyframes_at(keys, t):
    """Linearly interpolate a list of keyframes at normalised time t in [0, 1].

    Each keyframe is a dict of values plus an optional "t" (normalised time,
    0 = first frame, 1 = last frame). Keyframes without "t" are spread evenly.
    Fields missing from a keyframe are taken from the closest earlier one that
    has them.
    """
    if not keys:
        return {}
    n = len(keys)
    times = [k.get('t', (i / (n - 1) if n > 1 else 0.0)) for i, k in enumerate(keys)]
    if any(b < a for a, b in zip(times, times[1:])):
        raise ValueError('keyframe times must be non-decreasing: %r' % times)
    # complete every keyframe with the fields of its predecessors
    full, acc = [], {}
    for k in keys:
        acc = dict(acc)
        acc.update({f: v for f, v in k.items() if f != 't'})
        full.append(acc)
    if t <= times[0]:
        return dict(full[0])
    if t >= times[-1]:
        return dict(full[-1])
    for i in range(n - 1):
        if times[i] <= t <= times[i + 1]:
            span = times[i + 1] - times[i]
            w = 0.0 if span == 0 else (t - times[i]) / span
            a, b = full[i], full[i + 1]
            return {f: (lerp_value(a[f], b[f], w) if f in b else a[f]) for f in a}
    return dict(full[-1])


def derive_seed(base, frame, stream, index=0):
    """32-bit Mitsuba seed for one render call (stable across platforms).

    Streams used by main(): 'A@<spp>' and 'B@<spp>' (the two noisy estimates),
    'ref' (reference), 'aov' (Mitsuba AOVs), 'albedo' (directional albedo);
    `index` counts the passes of one render. The first four bytes of
    sha256("base/frame/stream/index"), little endian. Mitsuba's independent
    sampler hashes (seed, sample index) with TEA, so distinct seeds give
    statistically independent sample streams.
    """
    text = '%d/%d/%s/%d' % (base, frame, stream, index)
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:4], 'little')


# -----------------------------------------------------------------------------
# Camera
# -----------------------------------------------------------------------------

class Camera:
    """Pinhole camera: to_world (look_at convention) + field of view."""

    def __init__(self, to_world, fov, fov_axis, width, height, near=0.01, far=1000.0):
        self.to_world = np.asarray(to_world, dtype=np.float64)
        self.fov = float(fov)
        self.fov_axis = fov_axis
        self.width, self.height = int(width), int(height)
        self.near, self.far = float(near), float(far)
        aspect = self.width / self.height
        t = math.tan(math.radians(self.fov) / 2)
        axis = fov_axis
        if axis == 'smaller':
            axis = 'y' if aspect > 1 else 'x'
        elif axis == 'larger':
            axis = 'x' if aspect > 1 else 'y'
        if axis == 'x':
            self.tan_half_x = t
        elif axis == 'y':
            self.tan_half_x = t * aspect
        else:
            raise ValueError('fov_axis must be x, y, smaller or larger (got %r)' % fov_axis)
        self.tan_half_y = self.tan_half_x / aspect

    def sensor_dict(self, spp):
        return {
            'type': 'perspective',
            'to_world': mi.ScalarTransform4f(self.to_world),
            'fov': self.fov,
            'fov_axis': self.fov_axis,
            'near_clip': self.near,
            'far_clip': self.far,
            'sampler': {'type': 'independent', 'sample_count': int(spp)},
            'film': {
                'type': 'hdrfilm',
                'width': self.width,
                'height': self.height,
                'rfilter': {'type': 'box'},
                'pixel_format': 'rgb',
                'component_format': 'float32',
                'sample_border': False,
            },
        }

    def project(self, pts, w):
        """Project world points (w=1) or directions (w=0), arrays (N,3)/(N,).

        Returns continuous pixel coordinates (N,2) in the convention of the
        module docstring and a mask of entries in front of the camera.
        """
        inv = np.linalg.inv(self.to_world)
        local = pts @ inv[:3, :3].T + w[:, None] * inv[:3, 3][None, :]
        z = local[:, 2]
        ok = z > 1e-9
        zs = np.where(ok, z, 1.0)
        px = self.width * (0.5 - 0.5 * local[:, 0] / (zs * self.tan_half_x))
        py = self.height * (0.5 - 0.5 * local[:, 1] / (zs * self.tan_half_y))
        return np.stack([px, py], axis=-1), ok

    def describe(self):
        return {'to_world': self.to_world.tolist(), 'fov': self.fov, 'fov_axis': self.fov_axis,
                'tan_half_fov_x': self.tan_half_x, 'tan_half_fov_y': self.tan_half_y}


# -----------------------------------------------------------------------------
# Scene description -> Mitsuba dictionaries
# -----------------------------------------------------------------------------

OWN_KEYS = {'type', 'twosided', 'id'}


class SceneDesc:
    """A parsed scene JSON file plus the render settings resolved from the CLI."""

    def __init__(self, path, overrides):
        with open(path) as f:
            self.data = json.load(f)
        self.path = os.path.abspath(path)
        self.dir = os.path.dirname(self.path)
        d = self.data
        res = overrides.get('resolution') or d.get('resolution', [160, 96])
        self.width, self.height = int(res[0]), int(res[1])
        self.frames = int(overrides.get('frames') or d.get('frames', 1))
        self.spp = int(overrides.get('spp') or d.get('spp', 1))
        self.ref_spp = int(overrides.get('ref_spp') or d.get('ref_spp', 1024))
        self.aov_spp = int(overrides.get('aov_spp') or d.get('aov_spp', 32))
        seed = overrides.get('seed')
        self.seed = int(seed if seed is not None else d.get('seed', 0))
        self.max_depth = int(d.get('max_depth', 8))
        self.builtin = d.get('builtin')
        self.freeze_lights = bool(overrides.get('freeze_lights', False))
        self.materials = d.get('materials', {})
        self.shapes = d.get('shapes', [])
        self.emitters = d.get('emitters', [])
        self.camera_spec = d.get('camera')
        if self.builtin is None and self.camera_spec is None:
            raise ValueError('%s: a scene needs a "camera" (or a "builtin")' % path)
        if self.builtin not in (None, 'cornell_box'):
            raise ValueError('unknown builtin scene %r (known: cornell_box)' % self.builtin)
        for i, s in enumerate(self.shapes):
            s.setdefault('id', 'shape%d_%s' % (i, s.get('type', '?')))
        ids = [s['id'] for s in self.shapes]
        if len(set(ids)) != len(ids):
            raise ValueError('shape ids must be unique: %r' % ids)

    def time_of(self, frame):
        return frame / (self.frames - 1) if self.frames > 1 else 0.0

    # -- values --------------------------------------------------------------
    def convert(self, value, key=''):
        """JSON value -> Mitsuba dict value for material/emitter/texture params."""
        if isinstance(value, dict):
            if key == 'to_uv':
                s = value.get('scale', [1, 1])
                s = [s, s] if isinstance(s, (int, float)) else s
                m = np.diag([float(s[0]), float(s[1]), 1.0, 1.0])
                if 'translate' in value:
                    m[0, 3], m[1, 3] = value['translate'][0], value['translate'][1]
                return mi.ScalarTransform4f(m)
            if key == 'to_world':
                return mi.ScalarTransform4f(transform_matrix(value))
            if value.get('type') == 'spectrum' or value.get('type') == 'rgb':
                return dict(value)
            out = {}
            for k, v in value.items():
                if k in ('twosided', 'id'):
                    continue
                out[k] = self.convert(v, k)
            return self.wrap_twosided(value, out)
        if isinstance(value, (list, tuple)):
            if len(value) == 3 and all(isinstance(x, (int, float)) for x in value):
                return {'type': 'rgb', 'value': [float(x) for x in value]}
            raise ValueError('cannot convert list %r for parameter %r' % (value, key))
        if isinstance(value, str) and key == 'filename':
            return os.path.join(self.dir, value)
        return value  # numbers, strings, booleans unchanged

    @staticmethod
    def wrap_twosided(spec, out):
        if spec.get('twosided'):
            return {'type': 'twosided', 'bsdf': out}
        return out

    def material(self, ref):
        if isinstance(ref, str):
            if ref not in self.materials:
                raise ValueError('unknown material %r' % ref)
            spec = self.materials[ref]
        else:
            spec = ref
        if 'type' not in spec:
            raise ValueError('material without "type": %r' % (spec,))
        return self.convert(spec)

    # -- per-frame state -------------------------------------------------------
    def camera_at(self, t):
        if self.camera_spec is None:
            return None
        c = dict(self.camera_spec)
        c.update(keyframes_at(c.pop('keyframes', []), t))
        for k in ('origin', 'target'):
            if k not in c:
                raise ValueError('camera needs "%s"' % k)
        return Camera(look_at(c['origin'], c['target'], c.get('up', [0, 1, 0])),
                      c.get('fov', 45.0), c.get('fov_axis', 'x'), self.width, self.height,
                      c.get('near_clip', 0.01), c.get('far_clip', 1000.0))

    def shape_transform(self, s, t):
        spec = dict(s.get('transform', {}))
        if s.get('emitter') is not None and self.freeze_lights:
            t = 0.0
        spec.update(keyframes_at(s.get('keyframes', []), t))
        return transform_matrix(spec)

    def shape_is_static(self, s):
        return not s.get('keyframes')

    def build(self, t):
        """(scene dict, Camera, {shape id: to_world}) at normalised time t."""
        if self.builtin == 'cornell_box':
            return self.build_cornell(t)
        scene = {'type': 'scene',
                 'integrator': {'type': 'path', 'max_depth': self.max_depth}}
        cam = self.camera_at(t)
        scene['sensor'] = cam.sensor_dict(self.spp)
        mats = {}
        for s in self.shapes:
            m = self.shape_transform(s, t)
            mats[s['id']] = m
            d = {'type': s['type'], 'to_world': mi.ScalarTransform4f(m)}
            for k, v in s.get('params', {}).items():
                d[k] = self.convert(v, k)
            # a separate BSDF instance per shape keeps Mitsuba from merging
            # shapes that share a material, so every shape keeps its id
            if 'material' in s:
                d['bsdf'] = self.material(s['material'])
            if s.get('emitter') is not None:
                e = dict(s['emitter'])
                e.setdefault('type', 'area')
                d['emitter'] = self.convert(e)
            scene[s['id']] = d
        for i, e in enumerate(self.emitters):
            scene['emitter%d' % i] = self.emitter_dict(e, t)
        return scene, cam, mats

    def emitter_dict(self, e, t):
        e = dict(e)
        keys = e.pop('keyframes', [])
        e.update(keyframes_at(keys, 0.0 if self.freeze_lights else t))
        kind = e['type']
        out = {'type': kind}
        if kind == 'spot' or ('origin' in e and 'target' in e):
            if 'origin' not in e or 'target' not in e:
                raise ValueError('%s emitter needs "origin" and "target"' % kind)
            out['to_world'] = mi.ScalarTransform4f(
                look_at(e.pop('origin'), e.pop('target'), e.pop('up', [0, 1, 0])))
        if 'position' in e:
            out['position'] = mi.ScalarPoint3f(*[float(x) for x in vec3(e.pop('position'))])
        if 'direction' in e:
            out['direction'] = mi.ScalarVector3f(*[float(x) for x in vec3(e.pop('direction'))])
        for k, v in e.items():
            if k == 'type':
                continue
            out[k] = self.convert(v, k)
        return out

    def build_cornell(self, t):
        d = mi.cornell_box()
        sensor = d['sensor']
        to_world = np.array(sensor['to_world'].matrix, dtype=np.float64)
        if self.camera_spec is not None:
            cam = self.camera_at(t)
        else:
            cam = Camera(to_world, sensor['fov'], sensor.get('fov_axis', 'x'),
                         self.width, self.height, sensor.get('near_clip', 0.01),
                         sensor.get('far_clip', 1000.0))
        d['sensor'] = cam.sensor_dict(self.spp)
        d['integrator'] = {'type': 'path', 'max_depth': self.max_depth}
        return d, cam, {}


# -----------------------------------------------------------------------------
# Rendering
# -----------------------------------------------------------------------------

def sanitize(img, stats, key):
    bad = ~np.isfinite(img)
    n = int(bad.sum())
    if n:
        img = np.where(bad, 0.0, img)
    stats[key + '_nonfinite'] = stats.get(key + '_nonfinite', 0) + n
    return img


def render_radiance(scene, spp, seeds, max_lanes):
    """Mean of several independent mi.render passes totalling `spp` samples/pixel."""
    film = scene.sensors()[0].film()
    w, h = film.crop_size()
    per_pass = max(1, min(spp, max_lanes // (w * h)))
    acc = np.zeros((h, w, 3), dtype=np.float64)
    done, i = 0, 0
    while done < spp:
        n = min(per_pass, spp - done)
        img = np.array(mi.render(scene, spp=n, seed=seeds(i)), dtype=np.float64)[..., :3]
        acc += img * n
        done += n
        i += 1
    return acc / spp, i


AOV_SPEC = 'albedo:albedo,normal:sh_normal,depth:depth,position:position'
AOV_CHANNELS = {  # our channel name -> channel name in Mitsuba's film for AOV_SPEC
    'albedo.R': 'albedo.R', 'albedo.G': 'albedo.G', 'albedo.B': 'albedo.B',
    'normal.X': 'normal.X', 'normal.Y': 'normal.Y', 'normal.Z': 'normal.Z',
    'depth.Z': 'depth.T',
    'position.X': 'position.X', 'position.Y': 'position.Y', 'position.Z': 'position.Z',
}


def render_aovs(scene, aov_integrator, spp, seed):
    mi.render(scene, integrator=aov_integrator, spp=spp, seed=seed)
    bmp = scene.sensors()[0].film().bitmap()
    names = [bmp.struct_()[i].name for i in range(bmp.channel_count())]
    arr = np.array(bmp, dtype=np.float64)
    out = {}
    for ours, theirs in AOV_CHANNELS.items():
        if theirs not in names:
            raise RuntimeError('Mitsuba film has no channel %r (has %r)' % (theirs, names))
        out[ours] = arr[..., names.index(theirs)]
    return out


ALBEDO_SPP_FACTOR = 4  # albedo samples per pixel = 4 x --aov-spp (plastic lobes are noisy)


def render_directional_albedo(scene, cam, spp, seed, max_lanes):
    """Directional albedo of the visible surface, averaged over the pixel (H,W,3).

    For `spp` jittered camera rays per pixel (box footprint) the BSDF at the
    first hit is sampled once; the mean sampling weight f*cos/pdf estimates
    the fraction of light the surface reflects towards the camera (the
    hemispherical-directional reflectance, <= 1). On diffuse surfaces the
    weight is exactly the reflectance, so this equals Mitsuba's `albedo` AOV
    there; on conductors Mitsuba's AOV returns the BSDF value at normal
    incidence instead (values up to ~16 for a gold GGX alpha=0.12), which is
    no albedo. Misses and emitters without reflection give 0. JIT variants only.
    """
    w, h = cam.width, cam.height
    rng = np.random.default_rng(seed)
    sensor = scene.sensors()[0]
    ctx = mi.BSDFContext()
    out = np.zeros((h * w, 3))
    rows_per_chunk = max(1, max_lanes // (w * spp))
    for y0 in range(0, h, rows_per_chunk):
        y1 = min(h, y0 + rows_per_chunk)
        npx = (y1 - y0) * w
        pix = np.repeat(np.arange(y0 * w, y1 * w), spp)
        u = rng.random((5, pix.size))
        fx = (pix % w + u[0]) / w
        fy = (pix // w + u[1]) / h
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(mi.Float(fx), mi.Float(fy)),
                                   mi.Point2f(0.5))
        si = scene.ray_intersect(ray)
        valid = si.is_valid()
        bsdf = si.bsdf(ray)
        _, weight = bsdf.sample(ctx, si, mi.Float(u[2]), mi.Point2f(mi.Float(u[3]), mi.Float(u[4])),
                                valid)
        wgt = np.array(weight, dtype=np.float64).T
        wgt[~np.array(valid, dtype=bool)] = 0.0
        wgt[~np.isfinite(wgt)] = 0.0
        out[y0 * w:y1 * w] = wgt.reshape(npx, spp, 3).mean(axis=1)
    return out.reshape(h, w, 3)


def center_rays(scene, cam):
    """Trace one ray through every pixel centre.

    Returns (points (N,3), directions (N,3), hit mask (N,), shape index (N,)
    into scene.shapes(), -1 on a miss), pixels in row-major order.
    """
    w, h = cam.width, cam.height
    sensor = scene.sensors()[0]
    shapes = list(scene.shapes())
    if is_jit():
        idx = dr.arange(mi.UInt32, w * h)
        px = mi.Float(idx % w) + 0.5
        py = mi.Float(idx // w) + 0.5
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(px / w, py / h), mi.Point2f(0.5))
        si = scene.ray_intersect(ray)
        pts = np.array(si.p, dtype=np.float64).T
        dirs = np.array(ray.d, dtype=np.float64).T
        hit = np.array(si.is_valid(), dtype=bool)
        sid = np.full(w * h, -1, dtype=np.int64)
        for k, s in enumerate(shapes):
            m = np.array(si.shape == mi.ShapePtr(s), dtype=bool)
            sid[m & hit] = k
    else:
        pts = np.zeros((w * h, 3))
        dirs = np.zeros((w * h, 3))
        hit = np.zeros(w * h, dtype=bool)
        sid = np.full(w * h, -1, dtype=np.int64)
        ids = [s.id() for s in shapes]
        for i in range(w * h):
            x, y = i % w, i // w
            ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f((x + 0.5) / w, (y + 0.5) / h),
                                       mi.Point2f(0.5))
            si = scene.ray_intersect(ray)
            dirs[i] = [ray.d.x, ray.d.y, ray.d.z]
            if si.is_valid():
                hit[i] = True
                pts[i] = [si.p.x, si.p.y, si.p.z]
                sid[i] = ids.index(si.shape.id()) if si.shape.id() in ids else -1
    pts[~hit] = 0.0
    return pts, dirs, hit, sid


BEHIND_CAMERA_MOTION = -1.0e4  # motion of points behind the previous camera


def compute_motion(scene, cam, prev_cam, mats, prev_mats):
    """Motion (H,W,2) in pixels, plus diagnostics.

    For each pixel centre ray: hit point p on shape k -> previous world point
    M_k(t-1) M_k(t)^-1 p, projected with the previous camera. Rays that miss
    use the ray direction (a point at infinity, i.e. camera rotation only).
    """
    w, h = cam.width, cam.height
    pts, dirs, hit, sid = center_rays(scene, cam)
    shapes = list(scene.shapes())
    shape_ids = [s.id() for s in shapes]
    prev_pts = pts.copy()
    moved = 0
    for name, m in mats.items():
        pm = prev_mats.get(name)
        if pm is None or np.allclose(pm, m):
            continue
        if name not in shape_ids:
            raise RuntimeError('moving shape %r is not an individual Mitsuba shape '
                               '(shapes: %r)' % (name, shape_ids))
        sel = sid == shape_ids.index(name)
        delta = pm @ np.linalg.inv(m)
        prev_pts[sel] = pts[sel] @ delta[:3, :3].T + delta[:3, 3]
        moved += int(sel.sum())
    centres = np.stack(np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5), -1).reshape(-1, 2)
    # self-check: projecting with the current camera must give the pixel centres
    cur_proj, _ = cam.project(np.where(hit[:, None], pts, dirs), hit.astype(np.float64))
    selfcheck = float(np.abs(cur_proj - centres).max())
    q, ok = prev_cam.project(np.where(hit[:, None], prev_pts, dirs), hit.astype(np.float64))
    motion = q - centres
    motion[~ok] = BEHIND_CAMERA_MOTION
    info = {'selfcheck_max_px': selfcheck, 'moving_object_pixels': moved,
            'behind_prev_camera_pixels': int((~ok).sum()),
            'max_abs_motion_px': float(np.abs(motion[ok]).max()) if ok.any() else 0.0,
            'mean_abs_motion_px': float(np.abs(motion[ok]).mean()) if ok.any() else 0.0}
    return motion.reshape(h, w, 2), info


# -----------------------------------------------------------------------------
# EXR output
# -----------------------------------------------------------------------------

HALF_MAX = 65504.0


def write_exr(path, channels, half, stats=None):
    """Write {name: (H,W) array} as one scanline EXR, ZIP compressed."""
    import OpenEXR
    out = {}
    clamped = 0
    for name, a in channels.items():
        a = np.asarray(a, dtype=np.float64)
        a = np.where(np.isfinite(a), a, 0.0)
        if half:
            over = np.abs(a) > HALF_MAX
            clamped += int(over.sum())
            a = np.clip(a, -HALF_MAX, HALF_MAX).astype(np.float16)
        else:
            a = a.astype(np.float32)
        out[name] = np.ascontiguousarray(a)
    header = {'compression': OpenEXR.ZIP_COMPRESSION, 'type': OpenEXR.scanlineimage}
    tmp = path + '.tmp.exr'
    with OpenEXR.File(header, out) as f:
        f.write(tmp)
    os.replace(tmp, path)
    if stats is not None:
        stats['half_clamped'] = stats.get('half_clamped', 0) + clamped


def split3(img, names):
    return {n: img[..., i] for i, n in enumerate(names)}


# -----------------------------------------------------------------------------
# Main
# -----------------------------------------------------------------------------

def parse_args(argv):
    p = argparse.ArgumentParser(
        description='Render noisy/reference EXR frame sequences with AOVs and motion '
                    'vectors from a JSON scene description (see tools/README.md).')
    p.add_argument('scene', help='scene description (tools/scenes/*.json)')
    p.add_argument('--out', required=True, help='output directory')
    p.add_argument('--width', type=int, help='override the scene resolution (with --height)')
    p.add_argument('--height', type=int)
    p.add_argument('--frames', type=int, help='override the frame count')
    p.add_argument('--spp', type=int, help='samples/pixel of each noisy estimate (R,G,B and B.*)')
    p.add_argument('--ref-spp', type=int, help='samples/pixel of the reference')
    p.add_argument('--aov-spp', type=int, help='samples/pixel of the AOV render')
    p.add_argument('--seed', type=int, help='base seed (default: the scene\'s "seed")')
    p.add_argument('--dtype', choices=['half', 'float'], default='half',
                   help='pixel type of frame_NNNN.exr (default half)')
    p.add_argument('--ref-dtype', choices=['half', 'float'],
                   help='pixel type of ref/frame_NNNN.exr (default: --dtype)')
    p.add_argument('--no-ref', action='store_true', help='skip the reference renders')
    p.add_argument('--frame-range', help='render only frames A:B (python slice, end excluded)')
    p.add_argument('--resume', action='store_true',
                   help='skip frames whose output (and reference) files exist already')
    p.add_argument('--freeze-lights', action='store_true',
                   help='keep emitters at their first keyframe (for motion-vector checks)')
    p.add_argument('--albedo', choices=['reflectance', 'mitsuba'],
                   help='albedo.* channels: "reflectance" = directional albedo from BSDF '
                        'sampling (equals Mitsuba\'s AOV on diffuse surfaces, <= 1 on '
                        'metals), "mitsuba" = Mitsuba\'s albedo AOV as is; default: the '
                        'scene file\'s "albedo", else reflectance')
    p.add_argument('--variant', help='Mitsuba variant (default llvm_ad_rgb, scalar_rgb fallback)')
    p.add_argument('--max-lanes', type=int, default=1 << 24,
                   help='max samples in flight per mi.render pass (default 2^24)')
    return p.parse_args(argv)


def main(argv=None):
    args = parse_args(argv)
    if (args.width is None) != (args.height is None):
        sys.exit('render.py: give both --width and --height')
    variant = init_mitsuba(args.variant)
    overrides = {'resolution': [args.width, args.height] if args.width else None,
                 'frames': args.frames, 'spp': args.spp, 'ref_spp': args.ref_spp,
                 'aov_spp': args.aov_spp, 'seed': args.seed,
                 'freeze_lights': args.freeze_lights}
    desc = SceneDesc(args.scene, overrides)
    ref_half = (args.ref_dtype or args.dtype) == 'half'
    os.makedirs(args.out, exist_ok=True)
    if not args.no_ref:
        os.makedirs(os.path.join(args.out, 'ref'), exist_ok=True)
    frames = list(range(desc.frames))
    if args.frame_range:
        a, _, b = args.frame_range.partition(':')
        frames = frames[int(a) if a else 0:int(b) if b else None]

    aov_integrator = mi.load_dict({'type': 'aov', 'aovs': AOV_SPEC})
    albedo_mode = args.albedo or desc.data.get('albedo', 'reflectance')
    if albedo_mode not in ('reflectance', 'mitsuba'):
        sys.exit('render.py: %s: "albedo" must be reflectance or mitsuba' % args.scene)
    if albedo_mode == 'reflectance' and not is_jit():
        print('render.py: --albedo reflectance needs a JIT variant; writing Mitsuba\'s '
              'albedo AOV instead', file=sys.stderr)
        albedo_mode = 'mitsuba'
    info = {
        'generator': 'tools/render.py',
        'command': 'render.py ' + ' '.join(sys.argv[1:] if argv is None else argv),
        'scene': os.path.relpath(desc.path, os.path.dirname(os.path.abspath(__file__))),
        'mitsuba_version': mi.__version__, 'drjit_version': dr.__version__, 'variant': variant,
        'width': desc.width, 'height': desc.height, 'frames': desc.frames,
        'spp': desc.spp, 'b_spp': desc.spp, 'ref_spp': 0 if args.no_ref else desc.ref_spp,
        'aov_spp': desc.aov_spp, 'seed': desc.seed, 'freeze_lights': desc.freeze_lights,
        'dtype': args.dtype, 'ref_dtype': None if args.no_ref else ('half' if ref_half else 'float'),
        'rfilter': 'box', 'sampler': 'independent', 'albedo': albedo_mode,
        'albedo_spp': (ALBEDO_SPP_FACTOR if albedo_mode == 'reflectance' else 1) * desc.aov_spp,
        'channels': ['R', 'G', 'B', 'B.R', 'B.G', 'B.B', 'albedo.R', 'albedo.G', 'albedo.B',
                     'normal.X', 'normal.Y', 'normal.Z', 'depth.Z',
                     'position.X', 'position.Y', 'position.Z', 'motion.X', 'motion.Y'],
        'pixel_convention': 'pixel (x,y) centre = (x+0.5, y+0.5), x right, y down; '
                            'previous_position = current_position + motion',
        'frames_info': [],
    }
    t_start = time.time()
    prev_cam, prev_mats = None, None
    if frames and frames[0] > 0:  # rendering a sub-range: rebuild the previous frame's state
        _, prev_cam, prev_mats = desc.build(desc.time_of(frames[0] - 1))
    done = []
    for f in frames:
        t = desc.time_of(f)
        name = 'frame_%04d.exr' % f
        if args.resume and os.path.exists(os.path.join(args.out, name)) and (
                args.no_ref or os.path.exists(os.path.join(args.out, 'ref', name))):
            _, prev_cam, prev_mats = desc.build(t)
            done.append(f)
            continue
        t0 = time.time()
        scene_dict, cam, mats = desc.build(t)
        scene = mi.load_dict(scene_dict)
        stats = {}
        # the noisy streams depend on the spp, so e.g. the 1-spp and the 16-spp
        # renders of one scene share no random numbers; the reference does not
        stream_a, stream_b = 'A@%d' % desc.spp, 'B@%d' % desc.spp
        seed_a = derive_seed(desc.seed, f, stream_a)
        seed_b = derive_seed(desc.seed, f, stream_b)
        seed_aov = derive_seed(desc.seed, f, 'aov')
        noisy_a, _ = render_radiance(scene, desc.spp,
                                     lambda i: derive_seed(desc.seed, f, stream_a, i),
                                     args.max_lanes)
        noisy_b, _ = render_radiance(scene, desc.spp,
                                     lambda i: derive_seed(desc.seed, f, stream_b, i),
                                     args.max_lanes)
        noisy_a = sanitize(noisy_a, stats, 'A')
        noisy_b = sanitize(noisy_b, stats, 'B')
        t_noisy = time.time() - t0
        aovs = render_aovs(scene, aov_integrator, desc.aov_spp, seed_aov)
        if albedo_mode == 'reflectance':
            alb = render_directional_albedo(scene, cam, ALBEDO_SPP_FACTOR * desc.aov_spp,
                                            derive_seed(desc.seed, f, 'albedo'),
                                            min(args.max_lanes, 1 << 22))
            aovs.update(split3(alb, ['albedo.R', 'albedo.G', 'albedo.B']))
        for k in list(aovs):
            aovs[k] = sanitize(aovs[k], stats, 'aov')
        if prev_cam is None:
            motion = np.zeros((desc.height, desc.width, 2))
            minfo = {'selfcheck_max_px': None, 'note': 'first frame: motion = 0'}
            # still run the self-check on frame 0
            _, m0 = compute_motion(scene, cam, cam, mats, mats)
            minfo['selfcheck_max_px'] = m0['selfcheck_max_px']
        else:
            motion, minfo = compute_motion(scene, cam, prev_cam, mats, prev_mats)
        t_aux = time.time() - t0 - t_noisy
        channels = {}
        channels.update(split3(noisy_a, ['R', 'G', 'B']))
        channels.update(split3(noisy_b, ['B.R', 'B.G', 'B.B']))
        channels.update(aovs)
        channels['motion.X'] = motion[..., 0]
        channels['motion.Y'] = motion[..., 1]
        write_exr(os.path.join(args.out, name), channels, args.dtype == 'half', stats)
        ref_passes = 0
        t_ref = 0.0
        if not args.no_ref:
            t1 = time.time()
            ref, ref_passes = render_radiance(
                scene, desc.ref_spp, lambda i: derive_seed(desc.seed, f, 'ref', i), args.max_lanes)
            ref = sanitize(ref, stats, 'ref')
            write_exr(os.path.join(args.out, 'ref', name), split3(ref, ['R', 'G', 'B']),
                      ref_half, stats)
            t_ref = time.time() - t1
        fi = {'frame': f, 'time': t, 'camera': cam.describe(),
              'seeds': {'A': seed_a, 'B': seed_b, 'aov': seed_aov,
                        'ref_first_pass': derive_seed(desc.seed, f, 'ref', 0),
                        'ref_passes': ref_passes},
              'moving_shapes': {k: v.tolist() for k, v in mats.items()
                                if prev_mats is not None and k in prev_mats
                                and not np.allclose(prev_mats[k], v)},
              'motion': minfo, 'stats': stats,
              'seconds': {'noisy': round(t_noisy, 2), 'aov_motion': round(t_aux, 2),
                          'ref': round(t_ref, 2)}}
        info['frames_info'].append(fi)
        print('frame %d/%d  noisy %.1fs  aov+motion %.1fs  ref %.1fs  |motion|max %.2fpx  '
              'selfcheck %.2e px' % (f + 1, desc.frames, t_noisy, t_aux, t_ref,
                                     minfo.get('max_abs_motion_px', 0.0),
                                     minfo['selfcheck_max_px']), flush=True)
        prev_cam, prev_mats = cam, mats
    info['total_seconds'] = round(time.time() - t_start, 1)
    info_path = os.path.join(args.out, 'render_info.json')
    if (args.frame_range or done) and os.path.exists(info_path):  # merge with earlier partial runs
        with open(info_path) as fh:
            old = json.load(fh)
        rendered = [f for f in frames if f not in done]
        keep = [x for x in old.get('frames_info', []) if x['frame'] not in rendered]
        info['frames_info'] = sorted(keep + info['frames_info'], key=lambda x: x['frame'])
    with open(info_path, 'w') as fh:
        json.dump(info, fh, indent=1)
    print('wrote %d frame(s) to %s in %.1fs' % (len(frames) - len(done), args.out, time.time() - t_start))


if __name__ == '__main__':
    main()
