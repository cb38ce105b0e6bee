"""Render a frame with Mitsuba 3 and denoise it in memory with mcdenoise.

    python python/examples/mitsuba_denoise.py [--spp 1] [--method atrous]

Mitsuba's Cornell box at 1 sample per pixel, its albedo, shading normal,
depth and world position from Mitsuba's `aov` integrator, denoised by
mcdenoise.denoise without any file in between (the à-trous methods stop at
edges by position and normal: without the position they blur the box into
the wall behind it); prints the PSNR of the input and of the output against a
256-sample render. Needs the `mitsuba` package (its llvm_ad_rgb variant
needs libLLVM: tools/setup-render.sh installs both).
"""
import argparse
import os
import sys

import numpy as np

import mcdenoise


def psnr(x, ref):
    f = lambda v: np.clip(v, 0, 1) ** (1 / 2.2)
    mse = float(np.mean((f(x) - f(ref)) ** 2))
    return -10 * np.log10(max(mse, 1e-20))


def render(spp, method, variant=None):
    import mitsuba as mi
    if variant is None:
        variant = 'llvm_ad_rgb' if 'llvm_ad_rgb' in mi.variants() else 'scalar_rgb'
    mi.set_variant(variant)
    scene_dict = mi.cornell_box()
    scene_dict['sensor']['film']['width'] = 128
    scene_dict['sensor']['film']['height'] = 128
    scene_dict['sensor']['film']['rfilter'] = {'type': 'box'}
    scene = mi.load_dict(scene_dict)
    color = np.array(mi.render(scene, spp=spp, seed=1), dtype=np.float32)[..., :3]
    reference = np.array(mi.render(scene, spp=256, seed=2), dtype=np.float32)[..., :3]
    aov = mi.load_dict({'type': 'aov', 'aovs': 'albedo:albedo,normal:sh_normal,depth:depth,position:position'})
    mi.render(scene, integrator=aov, spp=16, seed=3)
    bmp = scene.sensors()[0].film().bitmap()
    names = [bmp.struct_()[i].name for i in range(bmp.channel_count())]
    a = np.array(bmp, dtype=np.float32)
    pick = lambda cs: np.ascontiguousarray(np.stack([a[..., names.index(c)] for c in cs], axis=-1))
    albedo = pick(['albedo.R', 'albedo.G', 'albedo.B'])
    normal = pick(['normal.X', 'normal.Y', 'normal.Z'])
    depth = pick(['depth.T'])
    position = pick(['position.X', 'position.Y', 'position.Z'])
    out = mcdenoise.denoise(color, albedo=albedo, normal=normal, depth=depth, position=position, method=method)
    return psnr(color, reference), psnr(out, reference)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--spp', type=int, default=1)
    p.add_argument('--method', default='atrous')
    p.add_argument('--variant')
    a = p.parse_args()
    before, after = render(a.spp, a.method, a.variant)
    print('Cornell box at %d spp: input %.2f dB, %s %.2f dB' % (a.spp, before, a.method, after))
    return 0


if __name__ == '__main__':
    sys.exit(main())
