#!/usr/bin/env python3
"""The manifest of a rendered training-data directory (tools/render-train.sh
writes it when it finishes; run it on its own on a directory being
rendered): DEST/manifest.json, with per sequence what was rendered and how
(size, frames present, spp of the inputs, the targets and the AOVs, the
albedo convention, the seed, the scene's description, its emitters' and
materials' types, bytes on disk), and per part and overall the totals and
the coverage (how many sequences of each spp, albedo convention, emitter
and material type, camera motion).

    python3 tools/data_manifest.py DEST [--parts train,val,test,hi] [--print]

Standard library only. A sequence whose last reference frame is missing is
listed with "complete": false and left out of the totals.
"""
import argparse
import collections
import json
import os
import sys

CAMERA_MOTIONS = ('fixed', 'pan', 'orbit', 'dolly', 'truck', 'shake')


def material_types(m, out):
    """Every material type in a (possibly nested) material description."""
    if isinstance(m, dict):
        if 'type' in m and m['type'] not in ('checkerboard', 'bitmap'):
            out.add(m['type'])
        for v in m.values():
            material_types(v, out)
    elif isinstance(m, list):
        for v in m:
            material_types(v, out)


def scene_facts(scene_json):
    try:
        with open(scene_json) as f:
            s = json.load(f)
    except (OSError, ValueError):
        return {}
    mats = set()
    for sh in s.get('shapes', []):
        material_types(sh.get('material', {}), mats)
        if 'emitter' in sh:
            mats.add('area emitter')
    material_types(s.get('materials', {}), mats)
    desc = s.get('description', '')
    motion = [m for m in CAMERA_MOTIONS if 'camera ' + m in desc]
    return {
        'description': desc,
        'emitters': sorted({e.get('type', '?') for e in s.get('emitters', [])} |
                           ({'area'} if 'area emitter' in mats else set())),
        'materials': sorted(mats - {'area emitter'}),
        'camera': motion[0] if motion else 'unknown',
        'shapes': len(s.get('shapes', [])),
    }


def sequence(dest, part, name):
    d = os.path.join(dest, part, name)
    info_path = os.path.join(d, 'render_info.json')
    try:
        with open(info_path) as f:
            info = json.load(f)
    except (OSError, ValueError):
        info = {}
    frames = sorted(x for x in os.listdir(d) if x.startswith('frame_') and x.endswith('.exr'))
    ref = os.path.join(d, 'ref')
    refs = sorted(x for x in os.listdir(ref) if x.endswith('.exr')) if os.path.isdir(ref) else []
    want = info.get('frames', len(frames))
    size = 0
    for root, _, files in os.walk(d):
        size += sum(os.path.getsize(os.path.join(root, x)) for x in files)
    row = {
        'part': part,
        'name': name,
        'complete': len(frames) >= want and len(refs) >= want and want > 0,
        'frames': len(frames),
        'width': info.get('width'),
        'height': info.get('height'),
        'spp': info.get('spp'),
        'b_spp': info.get('b_spp'),
        'ref_spp': info.get('ref_spp'),
        'aov_spp': info.get('aov_spp'),
        'albedo': info.get('albedo'),
        'seed': info.get('seed'),
        'variant': info.get('variant'),
        'mitsuba': info.get('mitsuba_version'),
        'bytes': size,
    }
    row.update(scene_facts(os.path.join(dest, 'scenes', name + '.json')))
    return row


def totals(rows):
    done = [r for r in rows if r['complete']]
    count = lambda key: dict(sorted(collections.Counter(str(r.get(key)) for r in done).items()))
    many = lambda key: dict(sorted(collections.Counter(v for r in done for v in r.get(key, [])).items()))
    return {
        'sequences': len(done),
        'incomplete': len(rows) - len(done),
        'frames': sum(r['frames'] for r in done),
        'bytes': sum(r['bytes'] for r in done),
        'spp': count('spp'),
        'ref_spp': count('ref_spp'),
        'albedo': count('albedo'),
        'camera': count('camera'),
        'emitters': many('emitters'),
        'materials': many('materials'),
    }


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('dest')
    p.add_argument('--parts', default='train,val,test,hi')
    p.add_argument('--print', action='store_true', help='print the totals')
    a = p.parse_args()
    if not os.path.isdir(a.dest):
        sys.exit('data_manifest: %s is not a directory' % a.dest)
    rows = []
    for part in a.parts.split(','):
        pd = os.path.join(a.dest, part)
        if not os.path.isdir(pd):
            continue
        for name in sorted(os.listdir(pd)):
            if os.path.isdir(os.path.join(pd, name)):
                rows.append(sequence(a.dest, part, name))
    parts = sorted({r['part'] for r in rows})
    manifest = {
        'generator': 'tools/gen_scenes.py + tools/render.py (tools/render-train.sh)',
        'total': totals(rows),
        'parts': {pt: totals([r for r in rows if r['part'] == pt]) for pt in parts},
        'sequences': rows,
    }
    out = os.path.join(a.dest, 'manifest.json')
    tmp = out + '.tmp'
    with open(tmp, 'w') as f:
        json.dump(manifest, f, indent=1)
    os.replace(tmp, out)
    if a.print:
        t = manifest['total']
        print('%s: %d sequences, %d frames, %.1f GB (%d incomplete)' %
              (out, t['sequences'], t['frames'], t['bytes'] / 1e9, t['incomplete']))
        for pt, v in manifest['parts'].items():
            print('  %-5s %4d sequences %6d frames  spp %s  albedo %s' %
                  (pt, v['sequences'], v['frames'], v['spp'], v['albedo']))
        for key in ('camera', 'emitters', 'materials'):
            print('  %s: %s' % (key, t[key]))


if __name__ == '__main__':
    main()
