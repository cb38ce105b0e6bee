#!/usr/bin/env python3
"""Per method, each precision's end-to-end time beside its error on rendered
sequences, and which precisions are on the Pareto front (no other
precision of the same method is at least as fast and at least as accurate,
and better in one): the table docs/performance.md shows, so that a user can
pick the fastest mode within an error budget.

    python3 tools/pareto.py E2E.txt QUALITY.json [QUALITY2.json ...]

E2E.txt is the output of `bash tools/speed-e2e.sh` (its per-method rows);
QUALITY.json are tools/eval_learned.py outputs (labels `wskp3 f32`,
`wskp3 fixed`, ...; a method scored only in f32, like `atrous`, gets its
f32 row's quality). The error columns: mean PSNR over the sequences (and
frames), the largest PSNR loss against f32 on any sequence, mean relMSE.
"""
import json
import sys

METHOD_LABEL = {'wskp3': 'wskp3', 'wskp6': 'wskp6', 'afn': 'afn', 'atrous': 'atrous', 'sure-atrous': 'sure-atrous'}


def read_e2e(path):
    rows = {}
    for line in open(path):
        f = line.split()
        if len(f) == 6 and f[1] in ('f32', 'f16', 'fixed', 'f16-arith'):
            try:
                rows[(f[0], f[1])] = (float(f[2]), float(f[3]))
            except ValueError:
                pass
    return rows


def quality(results, method, prec):
    """(mean PSNR, worst PSNR loss against f32, mean relMSE) over every sequence, or None."""
    label = '%s %s' % (method, prec)
    f32 = '%s f32' % method
    psnr, rel, loss = [], [], []
    for seqs in results:
        for v in seqs.values():
            m = v.get(label) or (v.get(method) if prec == 'f32' else None)
            if not m:
                continue
            psnr.append(m['mean']['psnr'])
            rel.append(m['mean']['relmse'])
            base = v.get(f32) or v.get(method)
            if base:
                loss.append(base['mean']['psnr'] - m['mean']['psnr'])
    if not psnr:
        return None
    return sum(psnr) / len(psnr), max(loss) if loss else 0.0, sum(rel) / len(rel)


def main():
    e2e = read_e2e(sys.argv[1])
    results = [json.load(open(p)) for p in sys.argv[2:]]
    print('| method | precision | wall ms/frame | kernels ms/frame | mean PSNR dB | worst loss vs f32 dB | mean relMSE | Pareto |')
    print('|---|---|---|---|---|---|---|---|')
    methods = []
    for (m, _p) in e2e:
        if m not in methods and m in METHOD_LABEL:
            methods.append(m)
    for m in methods:
        cand = []
        for p in ('f32', 'f16', 'fixed'):
            if (m, p) not in e2e:
                continue
            q = quality(results, METHOD_LABEL[m], p)
            cand.append((p, e2e[(m, p)], q))
        for p, (wall, kern), q in cand:
            if q is None:
                mark = 'not scored'
            else:
                dominated = any(
                    oq is not None and ow <= wall and oq[0] >= q[0] and (ow < wall or oq[0] > q[0])
                    for op, (ow, _), oq in cand if op != p)
                mark = 'no' if dominated else 'yes'
            qs = ('%.2f | %.2f | %.4f' % q) if q else ' | | '
            print('| %s | %s | %.0f | %.0f | %s | %s |' % (m, p, wall, kern, qs, mark))


if __name__ == '__main__':
    main()
