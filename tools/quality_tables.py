#!/usr/bin/env python3
"""The summary tables of docs/quality.md from the quality.json that
tools/eval_learned.py writes: each method's gain over its input and its
distance from OIDN high per sequence (PSNR dB), relMSE against the input's,
and the reduced precisions of the learned methods against their f32.

    python3 tools/quality_tables.py OUT/quality.json
"""
import json
import sys

GAIN = ['ta', 'atrous', 'sure-atrous', 'wskp3 f32', 'wskp6 f32', 'afn f32', 'oidn fast', 'oidn high']
# Both estimates (eval_learned's "(pair)" rows; cross always reads the pair).
GAIN_PAIR = ['ta (pair)', 'atrous (pair)', 'sure-atrous (pair)', 'wskp3 f32 (pair)', 'wskp6 f32 (pair)',
             'afn f32 (pair)', 'cross', 'oidn fast (pair)', 'oidn high (pair)']


def mean(v, label, key):
    m = v.get(label, {}).get('mean')
    return m[key] if m else None


def gap_table(r, gain, base, high):
    cols = [c for c in gain if c != high and any(c in v for v in r.values())]
    print('| sequence | %s | %s | ' % (base, high.replace('oidn', 'OIDN')) + ' | '.join(cols) + ' |')
    print('|---|---|---|' + '---|' * len(cols))
    for seq, v in r.items():
        inp, hi = mean(v, base, 'psnr'), mean(v, high, 'psnr')
        if inp is None:
            continue
        cells = ['%.2f' % inp, '%.2f (+%.2f)' % (hi, hi - inp) if hi is not None else '']
        for c in cols:
            p = mean(v, c, 'psnr')
            cells.append('' if p is None else '%+.2f / %+.2f' % (p - inp, p - hi) if hi is not None else '%+.2f' % (p - inp))
        print('| %s | %s |' % (seq, ' | '.join(cells)))


def main():
    r = json.load(open(sys.argv[1]))
    print('PSNR dB, one estimate each: the input, then each method as gain over the input / distance from OIDN high\n')
    gap_table(r, GAIN, 'input', 'oidn high')
    if any('input (pair)' in v for v in r.values()):
        print('\nPSNR dB with the pair (both estimates; OIDN on their mean), as above\n')
        gap_table(r, GAIN_PAIR, 'input (pair)', 'oidn high (pair)')
    print('\nrelMSE (the input\'s first)\n')
    cols = [c for c in ['input'] + GAIN + ['input (pair)'] + GAIN_PAIR if any(c in v for v in r.values())]
    print('| sequence | ' + ' | '.join(cols) + ' |')
    print('|---|' + '---|' * len(cols))
    for seq, v in r.items():
        cells = []
        for c in cols:
            x = mean(v, c, 'relmse')
            cells.append('' if x is None else '%.4f' % x)
        print('| %s | %s |' % (seq, ' | '.join(cells)))
    print('\nf16 storage and fixed point against f32 of the same method (PSNR dB difference)\n')
    models = [m for m in ('wskp3', 'wskp6', 'afn') if any(m + ' f32' in v for v in r.values())]
    print('| sequence | ' + ' | '.join('%s %s' % (m, p) for m in models for p in ('f16', 'fixed')) + ' |')
    print('|---|' + '---|' * (2 * len(models)))
    worst = 0.0
    for seq, v in r.items():
        cells = []
        for m in models:
            base = mean(v, m + ' f32', 'psnr')
            for p in ('f16', 'fixed'):
                x = mean(v, '%s %s' % (m, p), 'psnr')
                if base is None or x is None:
                    cells.append('')
                else:
                    cells.append('%+.2f' % (x - base))
                    worst = max(worst, abs(x - base))
        print('| %s | %s |' % (seq, ' | '.join(cells)))
    print('\nlargest difference: %.2f dB' % worst)


if __name__ == '__main__':
    sys.exit(main())
