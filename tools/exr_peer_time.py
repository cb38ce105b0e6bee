#!/usr/bin/env python3
"""OpenEXR's own reader and writer (its PyPI package, the C++ library) on a
frame file: the median of REPS reads of every channel and of REPS writes
of its R,G,B as f32 ZIP and f16 ZIP, for tools/io-side-by-side.sh.

    tools/.venv/bin/python tools/exr_peer_time.py FILE [--reps 10] [--threads N]
"""
import argparse
import os
import statistics
import tempfile
import time

import numpy as np
import OpenEXR


def main():
    p = argparse.ArgumentParser()
    p.add_argument('file')
    p.add_argument('--reps', type=int, default=10)
    p.add_argument('--threads', type=int, default=1, help="OpenEXR's global thread count")
    a = p.parse_args()
    OpenEXR.set_global_thread_count(a.threads)
    reads = []
    for _ in range(a.reps):
        t = time.perf_counter()
        with OpenEXR.File(a.file, separate_channels=True) as f:
            ch = {n: np.asarray(c.pixels) for n, c in f.channels().items()}
        reads.append(time.perf_counter() - t)
    rgb = {n: np.ascontiguousarray(ch[n].astype(np.float32)) for n in 'RGB'}
    out = os.path.join(tempfile.gettempdir(), 'exr-peer-%d.exr' % os.getpid())
    for label, conv in [('f32-zip', np.float32), ('f16-zip', np.float16)]:
        writes = []
        chans = {n: np.ascontiguousarray(v.astype(conv)) for n, v in rgb.items()}
        for _ in range(a.reps):
            t = time.perf_counter()
            with OpenEXR.File({'compression': OpenEXR.ZIP_COMPRESSION, 'type': OpenEXR.scanlineimage}, chans) as f:
                f.write(out)
            writes.append(time.perf_counter() - t)
        print('OpenEXR %s write R,G,B %s, %d thread(s): median %.1f ms' % (
            OpenEXR.__version__, label, a.threads, 1e3 * statistics.median(writes)))
    os.remove(out)
    print('OpenEXR %s read every channel (%d), %d thread(s): median %.1f ms' % (
        OpenEXR.__version__, len(ch), a.threads, 1e3 * statistics.median(reads)))


if __name__ == '__main__':
    main()
