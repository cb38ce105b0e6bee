#!/usr/bin/env python3
"""Sanity and motion-vector checks of a directory written by render.py.

    tools/.venv/bin/python tools/check_data.py DIR [--json out.json]

Checks, per frame:
  * the exact channel set of frame_NNNN.exr and ref/frame_NNNN.exr, finiteness;
  * noisy vs reference: mean ratio (unbiasedness) and the correlation of the
    errors (A - ref) and (B - ref), Pearson and Spearman; for independent A
    and B the Spearman value matches the null value printed beside it (B
    shifted by one pixel): both share a small positive bias from the common
    reference, e.g. zero-radiance samples rank by the reference value;
  * motion vectors (frames >= 1), three ways:
    geometry  - the surface point seen through each pixel centre at frame t,
                moved by the object's previous transform, is compared with the
                point Mitsuba's previous-frame camera sees through the
                pixel-centre + motion position (exact check of the projection);
    position  - position.* of frame t-1 warped (bilinear) by the motion is
                compared with position.* of frame t on static shapes (object
                space for moving shapes);
    radiance  - ref of frame t-1 warped by the motion vs ref of frame t on
                static diffuse surfaces, relative error, next to the error of
                the unwarped previous frame as a baseline. Meaningful only when
                lighting is static (render with --freeze-lights); otherwise the
                moving light changes the shading between frames. With --floor-dir
                (same render, another --seed) the difference of two independent
                references of the same frame is reported as the noise floor.
Masks drop pixels next to a change of shape (edges) and disocclusions (the
geometry check failing).
"""

import argparse
import json
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import render as R  # noqa: E402
from exrio import load_frame, stack, warp_bilinear  # noqa: E402

NOISY_CHANNELS = ['R', 'G', 'B', 'B.R', 'B.G', 'B.B', 'albedo.R', 'albedo.G', 'albedo.B',
                  'normal.X', 'normal.Y', 'normal.Z', 'depth.Z',
                  'position.X', 'position.Y', 'position.Z', 'motion.X', 'motion.Y']
DIFFUSE_TYPES = {'diffuse'}


def material_type(desc, shape):
    m = shape.get('material')
    if m is None:
        return None
    spec = desc.materials[m] if isinstance(m, str) else m
    return spec.get('type')


def interior(sid):
    """Pixels whose 3x3 neighbourhood has one shape id."""
    h, w = sid.shape
    pad = np.pad(sid, 1, mode='edge')
    ok = np.ones_like(sid, dtype=bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            ok &= pad[1 + dy:1 + dy + h, 1 + dx:1 + dx + w] == sid
    return ok


def frame_state(desc, f):
    sd, cam, mats = desc.build(desc.time_of(f))
    scene = R.mi.load_dict(sd)
    pts, dirs, hit, sid = R.center_rays(scene, cam)
    names = [s.id() for s in scene.shapes()]
    sid_names = np.array([names[i] if i >= 0 else '' for i in sid])
    return scene, cam, mats, pts, hit, sid_names


def geometry_check(desc, prev, cur, motion):
    """Distance between the re-traced previous hit and the moved current hit."""
    mi, dr = R.mi, R.dr
    scene_p, cam_p, mats_p = prev[0], prev[1], prev[2]
    _, cam, mats, pts, hit, sid = cur
    w, h = cam.width, cam.height
    moved = pts.copy()
    for name, m in mats.items():
        if name in mats_p and not np.allclose(mats_p[name], m):
            sel = sid == name
            d = mats_p[name] @ np.linalg.inv(m)
            moved[sel] = pts[sel] @ d[:3, :3].T + d[:3, 3]
    cx = (np.arange(w * h) % w) + 0.5
    cy = (np.arange(w * h) // w) + 0.5
    qx = cx + motion[..., 0].reshape(-1)
    qy = cy + motion[..., 1].reshape(-1)
    inside = (qx >= 0) & (qx < w) & (qy >= 0) & (qy < h) & hit
    ray, _ = scene_p.sensors()[0].sample_ray(0.0, 0.5, mi.Point2f(mi.Float(qx / w), mi.Float(qy / h)),
                                             mi.Point2f(0.5))
    si = scene_p.ray_intersect(ray)
    p_hit = np.array(si.p, dtype=np.float64).T
    valid = np.array(si.is_valid(), dtype=bool) & inside
    dist = np.linalg.norm(p_hit - moved, axis=1)
    depth = np.linalg.norm(moved - cam_p.to_world[:3, 3], axis=1)
    rel = np.where(valid, dist / np.maximum(depth, 1e-6), np.inf)
    visible = rel < 2e-3  # same surface point: not occluded in the previous frame
    return rel, visible, inside


def spearman(a, b):
    ra = np.argsort(np.argsort(a)).astype(np.float64)
    rb = np.argsort(np.argsort(b)).astype(np.float64)
    return float(np.corrcoef(ra, rb)[0, 1])


def stats(x):
    x = np.asarray(x, dtype=np.float64)
    if x.size == 0:
        return None
    return {'n': int(x.size), 'mean': float(x.mean()), 'median': float(np.median(x)),
            'p95': float(np.percentile(x, 95)), 'max': float(x.max())}


def main():
    ap = argparse.ArgumentParser(description='check a render.py output directory')
    ap.add_argument('dir')
    ap.add_argument('--json', help='write the results here too')
    ap.add_argument('--floor-dir', help='the same render with another --seed: the difference '
                                        'of the two references is reported as noise floor')
    a = ap.parse_args()
    with open(os.path.join(a.dir, 'render_info.json')) as fh:
        info = json.load(fh)
    R.init_mitsuba(info.get('variant'))
    desc = R.SceneDesc(os.path.join(HERE, info['scene']),
                       {'resolution': [info['width'], info['height']], 'frames': info['frames'],
                        'spp': info['spp'], 'ref_spp': info['ref_spp'] or None,
                        'aov_spp': info['aov_spp'], 'seed': info['seed'],
                        'freeze_lights': info.get('freeze_lights', False)})
    shape_by_id = {s['id']: s for s in desc.shapes}
    static_diffuse = {k for k, s in shape_by_id.items()
                      if not s.get('keyframes') and s.get('emitter') is None
                      and material_type(desc, s) in DIFFUSE_TYPES}
    static_any = {k for k, s in shape_by_id.items() if not s.get('keyframes')}
    if desc.builtin:  # built-in scenes: every named shape is static
        static_any = static_diffuse = None
    results = {'dir': a.dir, 'frames': []}
    prev = None
    prev_ch = None
    prev_ref = None
    for f in range(info['frames']):
        ch, ref = load_frame(a.dir, f)
        fr = {'frame': f}
        missing = sorted(set(NOISY_CHANNELS) - set(ch))
        extra = sorted(set(ch) - set(NOISY_CHANNELS))
        fr['channels_ok'] = not missing and not extra
        if missing or extra:
            fr['missing'], fr['extra'] = missing, extra
        fr['nonfinite'] = int(sum((~np.isfinite(v)).sum() for v in ch.values()))
        A = stack(ch, ['R', 'G', 'B'])
        B = stack(ch, ['B.R', 'B.G', 'B.B'])
        motion = stack(ch, ['motion.X', 'motion.Y'])
        if ref is not None:
            fr['ref_channels_ok'] = sorted(ref) == ['B', 'G', 'R']
            Rf = stack(ref, ['R', 'G', 'B'])
            fr['mean_ratio_A_over_ref'] = float(A.mean() / Rf.mean())
            fr['mean_ratio_B_over_ref'] = float(B.mean() / Rf.mean())
            ea, eb = (A - Rf).reshape(-1), (B - Rf).reshape(-1)
            fr['corr_errA_errB'] = float(np.corrcoef(ea, eb)[0, 1])
            # robust version (Spearman rank correlation), next to a null value:
            # the same with B shifted by one pixel, i.e. surely independent samples
            eb_null = (np.roll(B, 1, axis=1) - Rf).reshape(-1)
            fr['spearman_errA_errB'] = spearman(ea, eb)
            fr['spearman_errA_errB_null_shifted'] = spearman(ea, eb_null)
            fr['rel_mse_A'] = float(np.mean((A - Rf) ** 2 / (Rf ** 2 + 1e-2)))
        if f == 0:
            fr['max_abs_motion_frame0'] = float(np.abs(motion).max())
        cur = frame_state(desc, f)
        if prev is not None:
            rel, visible, inside = geometry_check(desc, prev, cur, motion)
            fr['geometry_rel_error_visible'] = stats(rel[visible])
            fr['geometry_visible_fraction_of_inside'] = float(visible.sum() / max(inside.sum(), 1))
            h, w = A.shape[:2]
            sid = cur[5].reshape(h, w)
            inner = interior(sid) & visible.reshape(h, w)
            # position check (world space on static shapes)
            P = stack(ch, ['position.X', 'position.Y', 'position.Z'])
            Pp = stack(prev_ch, ['position.X', 'position.Y', 'position.Z'])
            warped, ok = warp_bilinear(Pp, motion)
            static_mask = inner & ok & (np.isin(sid, list(static_any)) if static_any is not None
                                        else (sid != ''))
            err = np.linalg.norm(warped - P, axis=-1)
            base = np.linalg.norm(Pp - P, axis=-1)
            fr['position_static_err'] = stats(err[static_mask])
            fr['position_static_err_without_motion'] = stats(base[static_mask])
            # moving shapes: compare in object space
            mov = {}
            for name, m in cur[2].items():
                pm = prev[2].get(name)
                if pm is None or np.allclose(pm, m):
                    continue
                mask = inner & ok & (sid == name)
                if not mask.any():
                    continue
                obj = (P.reshape(-1, 3) @ np.linalg.inv(m)[:3, :3].T
                       + np.linalg.inv(m)[:3, 3]).reshape(h, w, 3)
                objp = (Pp.reshape(-1, 3) @ np.linalg.inv(pm)[:3, :3].T
                        + np.linalg.inv(pm)[:3, 3]).reshape(h, w, 3)
                wo, _ = warp_bilinear(objp, motion)
                scale = float(np.cbrt(abs(np.linalg.det(m[:3, :3]))))
                e = np.linalg.norm(wo - obj, axis=-1)[mask] * scale
                e0 = np.linalg.norm(objp - obj, axis=-1)[mask] * scale
                mov[name] = {'err_world_units': stats(e), 'err_without_motion': stats(e0)}
            fr['position_moving_objects'] = mov
            if ref is not None and prev_ref is not None:
                Rp = stack(prev_ref, ['R', 'G', 'B'])
                Rc = stack(ref, ['R', 'G', 'B'])
                wr, ok2 = warp_bilinear(Rp, motion)
                dmask = inner & ok2 & (np.isin(sid, list(static_diffuse)) if static_diffuse
                                       is not None else (sid != ''))
                lum = lambda x: x @ np.array([0.2126, 0.7152, 0.0722])  # noqa: E731
                denom = lum(Rc)[dmask] + 1e-3
                rel_w = np.abs(lum(wr)[dmask] - lum(Rc)[dmask]) / denom
                rel_0 = np.abs(lum(Rp)[dmask] - lum(Rc)[dmask]) / denom
                fr['radiance_static_diffuse_rel_err'] = stats(rel_w)
                fr['radiance_static_diffuse_rel_err_without_motion'] = stats(rel_0)
                fr['radiance_mask_pixels'] = int(dmask.sum())
                # the same away from texture edges (bilinear fetches blur the checkers)
                alb = stack(ch, ['albedo.R', 'albedo.G', 'albedo.B'])
                flat = np.ones(sid.shape, dtype=bool)
                pad = np.pad(alb, ((1, 1), (1, 1), (0, 0)), mode='edge')
                for dy in (-1, 0, 1):
                    for dx in (-1, 0, 1):
                        nb = pad[1 + dy:1 + dy + h, 1 + dx:1 + dx + w]
                        flat &= np.abs(nb - alb).max(axis=-1) < 0.02
                fm = flat[dmask]
                fr['radiance_static_diffuse_flat_rel_err'] = stats(rel_w[fm])
                fr['radiance_static_diffuse_flat_rel_err_without_motion'] = stats(rel_0[fm])
                if a.floor_dir:
                    _, ref2 = load_frame(a.floor_dir, f)
                    R2 = stack(ref2, ['R', 'G', 'B'])
                    rel_f = np.abs(lum(R2)[dmask] - lum(Rc)[dmask]) / denom
                    fr['noise_floor_two_refs_rel_err'] = stats(rel_f)
                    fr['noise_floor_two_refs_flat_rel_err'] = stats(rel_f[fm])
        results['frames'].append(fr)
        prev, prev_ch, prev_ref = cur, ch, ref
    print(json.dumps(results, indent=1))
    if a.json:
        with open(a.json, 'w') as fh:
            json.dump(results, fh, indent=1)


if __name__ == '__main__':
    main()
