#!/usr/bin/env python3
"""Scores every method on rendered held-out sequences and writes the tables
of docs/quality.md: per sequence, PSNR / SSIM / relMSE / flicker of the
input, TA, the classical denoisers, WSKP (3 and 6 layers, each precision),
AFN (with and without refinement, each precision), the PyTorch WSKP peer
and Intel Open Image Denoise.

    python3 tools/eval_learned.py --test /work/data/test --weights DIR -o OUT_DIR

DIR holds wskp6.safetensors, wskp3.safetensors, afn.safetensors and the
ablation's afn-ta-only.safetensors, afn-1spp-only.safetensors, WSKP's
single-size networks wskp3-k3 .. wskp3-k13.safetensors and their fused
counterpart wskp3-fused-1500.safetensors (made by
`mcdenoise train`, commands in docs/training.md) and optionally
torch_wskp6.safetensors (tools/torch_wskp.py train). OUT_DIR gets
quality.json (everything), quality.md (the tables) and per-frame PSNR CSVs.
Python: the tools/.venv-peers environment (tools/setup-peers.sh) for OIDN
and PyTorch; mcdenoise from target/release (or $MCDENOISE).
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def mcd():
    return os.environ.get('MCDENOISE', os.path.join(ROOT, 'target', 'release', 'mcdenoise'))


def run(cmd):
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError('%s failed: %s' % (' '.join(cmd), r.stderr.strip()))
    return r.stdout + r.stderr


def score(ref_dir, out_dir):
    j = json.loads(run([mcd(), 'score', '--reference', ref_dir, out_dir, '--json']).splitlines()[-1])
    return j


def has_pair(seq_dir):
    """Whether the sequence's first frame has the second estimate B.*."""
    first = sorted(f for f in os.listdir(seq_dir) if f.startswith('frame_') and f.endswith('.exr'))[0]
    with open(os.path.join(seq_dir, first), 'rb') as f:
        head = f.read(1 << 16)
    # The header's channel list: sorted names, each NUL-terminated and
    # followed by 16 bytes whose last is 0 (the y sampling's high byte).
    return b'\0B.R\0' in head


def methods(weights):
    """(label, kind, args): kind 'mcd' runs mcdenoise denoise, 'oidn' and 'torch' the peers."""
    w = lambda n: os.path.join(weights, n)
    m = [('input', 'mcd', ['--method', 'none']),
         ('ta', 'mcd', ['--method', 'ta']),
         ('atrous', 'mcd', ['--method', 'atrous']),
         ('sure-atrous', 'mcd', ['--method', 'sure-atrous'])]
    # The classical filter's reduced precisions.
    m += [('atrous ' + p, 'mcd', ['--method', 'atrous', '--precision', p]) for p in ('f16', 'fixed')]
    if os.path.exists(w('wskp6.safetensors')):
        for p in ('f32', 'f16', 'fixed'):
            m.append(('wskp6 ' + p, 'mcd', ['--method', 'wskp', '--layers', '6', '--weights', w('wskp6.safetensors'), '--precision', p]))
        m.append(('wskp6 int8', 'mcd', ['--method', 'wskp', '--layers', '6', '--weights', w('wskp6.safetensors'), '--emulate-int8']))
    if os.path.exists(w('wskp3.safetensors')):
        for p in ('f32', 'f16', 'fixed'):
            m.append(('wskp3 ' + p, 'mcd', ['--method', 'wskp', '--layers', '3', '--weights', w('wskp3.safetensors'), '--precision', p]))
        m.append(('wskp3 int8', 'mcd', ['--method', 'wskp', '--layers', '3', '--weights', w('wskp3.safetensors'), '--emulate-int8']))
    if os.path.exists(w('afn.safetensors')):
        m.append(('afn no-refine', 'mcd', ['--method', 'afn', '--weights', w('afn.safetensors'), '--no-refine']))
        for p in ('f32', 'f16', 'fixed'):
            m.append(('afn ' + p, 'mcd', ['--method', 'afn', '--weights', w('afn.safetensors'), '--precision', p]))
        m.append(('afn int8', 'mcd', ['--method', 'afn', '--weights', w('afn.safetensors'), '--emulate-int8']))
    # The paper's ablation (its Table 11): the same network trained on one
    # input only (`mcdenoise train --method afn --variant ...`), with its
    # refinement as trained.
    for v in ('ta-only', '1spp-only'):
        if os.path.exists(w('afn-%s.safetensors' % v)):
            m.append(('afn ' + v, 'mcd', ['--method', 'afn', '--weights', w('afn-%s.safetensors' % v)]))
    # The WSKP paper's Fig. 9: one window size against the six fused, WSKP-3
    # at one training budget (tools/train-all.sh wskp3-k3 .. wskp3-k13,
    # wskp3-fused-1500); the sizes come from the files' metadata.
    for k in ('fused-1500', 'k3', 'k5', 'k7', 'k9', 'k11', 'k13'):
        if os.path.exists(w('wskp3-%s.safetensors' % k)):
            m.append(('wskp3 ' + k, 'mcd', ['--method', 'wskp', '--layers', '3', '--weights', w('wskp3-%s.safetensors' % k)]))
    m.append(('cross', 'mcd', ['--method', 'cross']))
    if os.path.exists(w('torch_wskp6.safetensors')):
        m.append(('pytorch wskp6', 'torch', ['--weights', w('torch_wskp6.safetensors'), '--layers', '6']))
    m.append(('oidn fast', 'oidn', ['--quality', 'fast']))
    m.append(('oidn high', 'oidn', ['--quality', 'high']))
    # Every row above sees one estimate, the frames' R,G,B (`--pair first`;
    # OIDN's default), except `cross`, which regresses on the pair. The
    # rows "(pair)" see both estimates where the frames carry them: the
    # methods as users run them (`--pair mean`, the default: twice the
    # samples), beside OIDN on the pair's mean.
    m = [(l, k, a + ['--pair', 'first'] if k == 'mcd' and l != 'cross' else a) for l, k, a in m]
    m += [('input (pair)', 'mcd', ['--method', 'none']),
          ('ta (pair)', 'mcd', ['--method', 'ta']),
          ('atrous (pair)', 'mcd', ['--method', 'atrous']),
          ('sure-atrous (pair)', 'mcd', ['--method', 'sure-atrous'])]
    for name, args in (('wskp3', ['--method', 'wskp', '--layers', '3']), ('wskp6', ['--method', 'wskp', '--layers', '6']),
                       ('afn', ['--method', 'afn'])):
        if os.path.exists(w(name + '.safetensors')):
            m.append(('%s f32 (pair)' % name, 'mcd', args + ['--weights', w(name + '.safetensors')]))
    m.append(('oidn fast (pair)', 'oidn', ['--quality', 'fast', '--color', 'ab-mean']))
    m.append(('oidn high (pair)', 'oidn', ['--quality', 'high', '--color', 'ab-mean']))
    return m


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('--test', required=True)
    p.add_argument('--weights', required=True)
    p.add_argument('-o', '--output', required=True)
    p.add_argument('--only', help='comma-separated method labels')
    p.add_argument('--merge', help='an earlier quality.json: its results are kept where this run does not '
                                   'redo them (with --only, to re-score some methods; for the contact sheets '
                                   'copy its frames/ directory into OUT_DIR first)')
    p.add_argument('--summary', default='input,ta,atrous,sure-atrous,wskp3 f32,wskp6 f32,afn f32,oidn fast,oidn high',
                   help='methods of the summary table (PSNR and relMSE per sequence)')
    p.add_argument('--summary-pair', default='input (pair),ta (pair),atrous (pair),sure-atrous (pair),wskp3 f32 (pair),'
                                             'wskp6 f32 (pair),afn f32 (pair),cross,oidn fast (pair),oidn high (pair)',
                   help='methods of the second summary table: both estimates, where the frames carry them')
    p.add_argument('--sheets', default='input,ta,wskp3 f32,wskp6 f32,afn f32,oidn high',
                   help='methods of the contact sheet written per sequence (OUT_DIR/sheet_SEQ.png: the last '
                        'frame of each, then the reference; needs tools/.venv for OpenEXR); empty: none')
    a = p.parse_args()
    sheet_py = os.path.join(HERE, '.venv', 'bin', 'python')
    py = os.path.join(HERE, '.venv-peers', 'bin', 'python')
    seqs = sorted(d for d in os.listdir(a.test) if os.path.isdir(os.path.join(a.test, d)))
    results = {}
    if a.merge:
        with open(a.merge) as f:
            earlier = json.load(f)
    else:
        earlier = {}
    os.makedirs(a.output, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for seq in seqs:
            sd = os.path.join(a.test, seq)
            results[seq] = {}
            for label, kind, args in methods(a.weights):
                if a.only and label not in a.only.split(','):
                    if label in earlier.get(seq, {}):
                        results[seq][label] = earlier[seq][label]
                    continue
                if label.endswith('(pair)') and not has_pair(sd):
                    continue
                od = os.path.join(tmp, seq, label.replace(' ', '_').replace('(', '').replace(')', ''))
                if kind == 'mcd':
                    run([mcd(), 'denoise'] + args + ['--threads', '2', sd, '-o', od])
                elif kind == 'oidn':
                    run([py, os.path.join(HERE, 'oidn_denoise.py'), sd, '-o', od] + args)
                else:
                    run([py, os.path.join(HERE, 'torch_wskp.py'), 'denoise'] + args + [sd, '-o', od])
                j = score(os.path.join(sd, 'ref'), od)
                if a.sheets and label in a.sheets.split(','):
                    last = sorted(f for f in os.listdir(od) if f.endswith('.exr'))[-1]
                    keep = os.path.join(a.output, 'frames', seq)
                    os.makedirs(keep, exist_ok=True)
                    with open(os.path.join(od, last), 'rb') as src, \
                            open(os.path.join(keep, label.replace(' ', '_') + '.exr'), 'wb') as dst:
                        dst.write(src.read())
                if j['mean']['psnr'] is None or any(f['psnr'] is None for f in j['files']):
                    # A black reference scored against a black output: no
                    # finite PSNR (`mcdenoise score` gives null).
                    print('%-16s %-16s skipped: PSNR not finite (a black reference?)' % (seq, label), flush=True)
                    continue
                results[seq][label] = {'mean': j['mean'], 'psnr': [f['psnr'] for f in j['files']]}
                print('%-16s %-16s PSNR %6.2f dB  SSIM %.4f  relMSE %.5f  flicker %s' % (
                    seq, label, j['mean']['psnr'], j['mean']['ssim'], j['mean']['relmse'], j['mean']['flicker']), flush=True)
            if a.sheets and os.path.exists(sheet_py):
                keep = os.path.join(a.output, 'frames', seq)
                labels = [l for l in a.sheets.split(',') if os.path.exists(os.path.join(keep, l.replace(' ', '_') + '.exr'))]
                refs = sorted(f for f in os.listdir(os.path.join(sd, 'ref')) if f.endswith('.exr'))
                files = [os.path.join(keep, l.replace(' ', '_') + '.exr') for l in labels] + [os.path.join(sd, 'ref', refs[-1])]
                out = os.path.join(a.output, 'sheet_%s.png' % seq)
                run([sheet_py, os.path.join(HERE, 'contact_sheet.py'), out] + files + ['--cols', '4', '--scale', '2'])
                print('%s: %s + reference' % (out, ', '.join(labels)), flush=True)
    results = {seq: r for seq, r in results.items() if r}
    with open(os.path.join(a.output, 'quality.json'), 'w') as f:
        json.dump(results, f, indent=1)
    lines = []
    for seq, r in results.items():
        base = r.get('input', {}).get('mean', {}).get('psnr')
        lines.append('\n### %s\n' % seq)
        lines.append('| method | PSNR dB | gain over input dB | SSIM | relMSE | flicker |')
        lines.append('|---|---|---|---|---|---|')
        for label, v in r.items():
            m = v['mean']
            gain = '%.2f' % (m['psnr'] - base) if base is not None else ''
            fl = '%.4f' % m['flicker'] if m['flicker'] is not None else ''
            lines.append('| %s | %.2f | %s | %.4f | %.4f | %s |' % (label, m['psnr'], gain, m['ssim'], m['relmse'], fl))
        with open(os.path.join(a.output, 'psnr_%s.csv' % seq), 'w') as f:
            labels = list(r)
            f.write('frame,' + ','.join(labels) + '\n')
            for i in range(len(r[labels[0]]['psnr'])):
                f.write('%d,' % i + ','.join('%.3f' % r[l]['psnr'][i] for l in labels) + '\n')
    def table(labels):
        cols = [c for c in labels.split(',') if any(c in r for r in results.values())]
        rows = ['| sequence | ' + ' | '.join(cols) + ' |', '|---|' + '---|' * len(cols)]
        for seq, r in results.items():
            cells = []
            for c in cols:
                m = r.get(c, {}).get('mean')
                cells.append('%.2f (%.4f)' % (m['psnr'], m['relmse']) if m else '')
            if any(cells):
                rows.append('| %s | %s |' % (seq, ' | '.join(cells)))
        return '\n'.join(rows)
    with open(os.path.join(a.output, 'quality.md'), 'w') as f:
        f.write('PSNR dB (relMSE), mean over the frames; one estimate each (cross: the pair)\n\n'
                + table(a.summary) + '\n\nWith the pair, where the frames carry it\n\n' + table(a.summary_pair)
                + '\n' + '\n'.join(lines) + '\n')
    print('wrote %s' % a.output)


if __name__ == '__main__':
    sys.exit(main())
