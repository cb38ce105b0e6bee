#!/usr/bin/env python3
"""WSKP (weight-sharing kernel prediction) in PyTorch: the peer the Rust
implementation is measured against, written from the paper and the
authors' facts in shared/reference.md to the same contract as
std-host/src/wskp.rs (inputs, RepVGG ImportanceNet, fused filter, SMAPE).

    python tools/torch_wskp.py time [--threads 2]
    python tools/torch_wskp.py train --data DIR --minutes 20 -o W.safetensors [--layers 6 --batch 8 --crop 64]
    python tools/torch_wskp.py denoise --weights W --layers 6 IN_DIR -o OUT_DIR
    python tools/torch_wskp.py fixture -o tests/fixtures/wskp_torch

Temporal accumulation comes from mcdenoise itself (`mcdenoise denoise
--method ta`, path in $MCDENOISE or target/release/mcdenoise), so both
sides filter the same accumulated radiance. Weights are written in
mcdenoise's safetensors layout (std-host/src/nn/weights.rs), so
`mcdenoise denoise --method wskp --weights W` runs them too.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
import torch
import torch.nn.functional as F

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import exrio  # noqa: E402

EPS = 0.01
SIZES = [3, 5, 7, 9, 11, 13]


def mcdenoise_bin():
    return os.environ.get('MCDENOISE', os.path.join(HERE, '..', 'target', 'release', 'mcdenoise'))


# --- the network -------------------------------------------------------------

class RepBlock(torch.nn.Module):
    """5x5 + 3x3 + 1x1 convolutions (+ identity when cin == cout), no bias."""

    def __init__(self, cin, cout):
        super().__init__()
        self.conv5 = torch.nn.Conv2d(cin, cout, 5, padding=2, bias=False)
        self.conv3 = torch.nn.Conv2d(cin, cout, 3, padding=1, bias=False)
        self.conv1 = torch.nn.Conv2d(cin, cout, 1, padding=0, bias=False)
        self.identity = cin == cout

    def forward(self, x):
        y = self.conv5(x) + self.conv3(x) + self.conv1(x)
        return y + x if self.identity else y

    def merged(self):
        w = self.conv5.weight.detach().clone()
        w[:, :, 1:4, 1:4] += self.conv3.weight.detach()
        w[:, :, 2:3, 2:3] += self.conv1.weight.detach()
        if self.identity:
            for o in range(w.shape[0]):
                w[o, o, 2, 2] += 1.0
        return w


def channels(layers):
    if layers == 6:
        return [(10, 14), (14, 14), (14, 14), (14, 14), (14, 14), (14, 12)]
    if layers == 3:
        return [(10, 14), (14, 14), (14, 12)]
    raise ValueError('layers must be 3 or 6')


class ImportanceNet(torch.nn.Module):
    def __init__(self, layers):
        super().__init__()
        self.blocks = torch.nn.ModuleList([RepBlock(a, b) for a, b in channels(layers)])

    def forward(self, x):
        for i, b in enumerate(self.blocks):
            x = b(x)
            if i + 1 < len(self.blocks):
                x = F.leaky_relu(x, 0.1)
        return x


class MergedNet(torch.nn.Module):
    """The inference form: one 5x5 convolution per layer."""

    def __init__(self, net):
        super().__init__()
        self.weights = [b.merged() for b in net.blocks]

    def forward(self, x):
        for i, w in enumerate(self.weights):
            x = F.conv2d(x, w, padding=2)
            if i + 1 < len(self.weights):
                x = F.leaky_relu(x, 0.1)
        return x


def fused_filter(logits, c, alb):
    """out = alb * sum_k alpha_k * box(e_k c) / box(e_k), e_k = exp(I_k - max)."""
    imp, fus = logits[:, :6], logits[:, 6:]
    alpha = torch.softmax(fus, dim=1)
    out = 0
    for i, k in enumerate(SIZES):
        li = imp[:, i:i + 1]
        # One shift per image and size (the official code shifts nothing);
        # a tiny floor keeps an all-underflowed window finite.
        e = torch.exp(li - li.amax(dim=(2, 3), keepdim=True))
        r = k // 2
        num = F.avg_pool2d(e * c, k, stride=1, padding=r, count_include_pad=True)
        den = F.avg_pool2d(e, k, stride=1, padding=r, count_include_pad=True)
        out = out + alpha[:, i:i + 1] * num / (den + 1e-30)
    return alb * out


def smape(x, r):
    return (torch.abs(x - r) / (torch.abs(x) + torch.abs(r) + 0.01)).mean()


# --- data -------------------------------------------------------------------

def frame_inputs(frame, ta):
    """(x [10,H,W], c [3,H,W], alb [3,H,W]) as std-host/src/wskp.rs builds them."""
    t = np.stack([ta['R'], ta['G'], ta['B']])
    a = np.stack([frame['albedo.R'], frame['albedo.G'], frame['albedo.B']])
    n = np.stack([frame['normal.X'], frame['normal.Y'], frame['normal.Z']])
    d = frame['depth.Z']
    span = d.max() - d.min()
    dn = (d - d.min()) / span if span > 0 else np.zeros_like(d)
    x = np.concatenate([np.clip(t, 0, 1) ** (1 / 2.2), a, n * 0.5 + 0.5, dn[None]]).astype(np.float32)
    alb = (a + EPS).astype(np.float32)
    return x, (t / alb).astype(np.float32), alb


def accumulate(seq_dir, out_dir):
    subprocess.run([mcdenoise_bin(), 'denoise', '--method', 'ta', '--threads', '2', seq_dir, '-o', out_dir],
                   check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def load_sequence(seq_dir, tmp):
    ta_dir = os.path.join(tmp, os.path.basename(os.path.normpath(seq_dir)))
    accumulate(seq_dir, ta_dir)
    names = sorted(f for f in os.listdir(seq_dir) if f.endswith('.exr'))
    out = []
    for nme in names:
        fr = exrio.read_exr(os.path.join(seq_dir, nme))
        ta = exrio.read_exr(os.path.join(ta_dir, nme))
        x, c, alb = frame_inputs(fr, ta)
        ref = None
        rp = os.path.join(seq_dir, 'ref', nme)
        if os.path.exists(rp):
            rf = exrio.read_exr(rp)
            ref = np.stack([rf['R'], rf['G'], rf['B']]).astype(np.float32)
        noisy = np.stack([fr['R'], fr['G'], fr['B']]).astype(np.float32)
        out.append((nme, x, c, alb, ref, noisy))
    return out


def sequence_dirs(d):
    if any(f.endswith('.exr') for f in os.listdir(d)):
        return [d]
    return sorted(os.path.join(d, s) for s in os.listdir(d) if os.path.isdir(os.path.join(d, s)))


# --- weights ----------------------------------------------------------------

def save_weights(net, path, layers, form='branches'):
    from safetensors.numpy import save_file
    t = {}
    for i, b in enumerate(net.blocks):
        if form == 'branches':
            for k in (5, 3, 1):
                t['layers.%d.conv%d.weight' % (i, k)] = getattr(b, 'conv%d' % k).weight.detach().cpu().numpy().astype(np.float32)
        else:
            t['layers.%d.weight' % i] = b.merged().cpu().numpy().astype(np.float32)
    save_file(t, path, metadata={'format': 'mcdenoise-wskp', 'version': '1', 'form': form, 'layers': str(layers)})


def load_weights(net, path):
    from safetensors.numpy import load_file
    t = load_file(path)
    with torch.no_grad():
        for i, b in enumerate(net.blocks):
            for k in (5, 3, 1):
                getattr(b, 'conv%d' % k).weight.copy_(torch.from_numpy(t['layers.%d.conv%d.weight' % (i, k)]))


# --- commands ---------------------------------------------------------------

def psnr(x, r):
    d = np.clip(x, 0, 1) ** (1 / 2.2) - np.clip(r, 0, 1) ** (1 / 2.2)
    return 10 * np.log10(1.0 / max(np.mean(d * d), 1e-20))


def cmd_train(a):
    torch.manual_seed(a.seed)
    rng = np.random.default_rng(a.seed)
    torch.set_num_threads(a.threads)
    with tempfile.TemporaryDirectory() as tmp:
        frames = [f for d in sequence_dirs(a.data) for f in load_sequence(d, tmp)]
        val = [load_sequence(d, tmp) for d in sequence_dirs(a.val)] if a.val else []
    frames = [f for f in frames if f[4] is not None]
    net = ImportanceNet(a.layers)
    opt = torch.optim.Adam(net.parameters(), lr=a.lr)
    s = a.crop
    t0, step = time.time(), 0
    log = []
    while time.time() - t0 < a.minutes * 60:
        xs, cs, als, rs = [], [], [], []
        for _ in range(a.batch):
            _, x, c, alb, ref, _ = frames[rng.integers(len(frames))]
            h, w = x.shape[1:]
            y0, x0, t = rng.integers(h - s + 1), rng.integers(w - s + 1), rng.integers(8)
            crop = [v[:, y0:y0 + s, x0:x0 + s] for v in (x, c, alb, ref)]
            if t & 4:
                crop = [v.transpose(0, 2, 1) for v in crop]
            if t & 1:
                crop = [v[:, :, ::-1] for v in crop]
            if t & 2:
                crop = [v[:, ::-1, :] for v in crop]
            for lst, v in zip((xs, cs, als, rs), crop):
                lst.append(np.ascontiguousarray(v))
        x, c, alb, ref = (torch.from_numpy(np.stack(v)) for v in (xs, cs, als, rs))
        out = fused_filter(net(x), c, alb)
        loss = smape(out, ref)
        opt.zero_grad()
        loss.backward()
        opt.step()
        step += 1
        if step % 100 == 0:
            el = time.time() - t0
            msg = 'step %d  loss %.4f  %.2f steps/s' % (step, loss.item(), step / el)
            if val and step % 500 == 0:
                msg += '  val PSNR %.2f dB' % validate(net, val)
            print(msg, flush=True)
            log.append((step, el, loss.item()))
    save_weights(net, a.output, a.layers)
    print('trained %d steps in %.1f s; weights %s' % (step, time.time() - t0, a.output))
    if val:
        print('validation PSNR %.2f dB' % validate(net, val))


@torch.no_grad()
def run_frames(net, seq):
    m = MergedNet(net)
    outs = []
    for nme, x, c, alb, ref, noisy in seq:
        o = fused_filter(m(torch.from_numpy(x)[None]), torch.from_numpy(c)[None], torch.from_numpy(alb)[None])
        outs.append((nme, o[0].numpy(), ref, noisy))
    return outs


def validate(net, seqs):
    ps = [psnr(o, r) for seq in seqs for _, o, r, _ in run_frames(net, seq)]
    return float(np.mean(ps))


def cmd_denoise(a):
    torch.set_num_threads(a.threads)
    net = ImportanceNet(a.layers)
    load_weights(net, a.weights)
    os.makedirs(a.output, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        seq = load_sequence(a.input, tmp)
    for nme, o, _, _ in run_frames(net, seq):
        write_rgb(os.path.join(a.output, nme), o)
    print('wrote %d frames to %s' % (len(seq), a.output))


def write_rgb(path, img):
    import OpenEXR
    ch = {'R': img[0].astype(np.float32), 'G': img[1].astype(np.float32), 'B': img[2].astype(np.float32)}
    hdr = {'compression': OpenEXR.ZIP_COMPRESSION, 'type': OpenEXR.scanlineimage}
    with OpenEXR.File(hdr, ch) as f:
        f.write(path)


def median_ms(fn, reps):
    for _ in range(3):
        fn()
    t = []
    for _ in range(reps):
        s = time.perf_counter()
        fn()
        t.append((time.perf_counter() - s) * 1e3)
    t.sort()
    return t[len(t) // 2]


def cmd_time(a):
    torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    cpu = subprocess.run(['lscpu'], capture_output=True, text=True).stdout
    model = next((l.split(':', 1)[1].strip() for l in cpu.splitlines() if l.startswith('Model name')), '?')
    print('CPU %s; torch %s, %d threads' % (model, torch.__version__, torch.get_num_threads()))
    res = {}
    for layers in (6, 3):
        net = ImportanceNet(layers)
        opt = torch.optim.Adam(net.parameters(), lr=1e-3)
        b, s = 8, 128
        x, c, alb, ref = torch.rand(b, 10, s, s), torch.rand(b, 3, s, s) * 4, torch.rand(b, 3, s, s) + 0.05, torch.rand(b, 3, s, s)

        def step():
            loss = smape(fused_filter(net(x), c, alb), ref)
            opt.zero_grad()
            loss.backward()
            opt.step()
        ms = median_ms(step, a.reps)
        res['train_step_wskp%d_b8_128' % layers] = ms
        print('training step WSKP-%d, batch 8 of 128x128: %.1f ms' % (layers, ms))
        m = MergedNet(net)
        xi, ci, ai = torch.rand(1, 10, 720, 1280), torch.rand(1, 3, 720, 1280), torch.rand(1, 3, 720, 1280) + 0.05
        with torch.no_grad():
            ms_net = median_ms(lambda: m(xi), max(3, a.reps // 4))
            lg = m(xi)
            ms_filt = median_ms(lambda: fused_filter(lg, ci, ai), max(3, a.reps // 4))
        res['infer_net_wskp%d_1280x720' % layers] = ms_net
        res['infer_filter_1280x720'] = ms_filt
        print('inference 1280x720 WSKP-%d: network %.1f ms, fused filter %.1f ms, total %.1f ms' % (layers, ms_net, ms_filt, ms_net + ms_filt))
    if a.json:
        with open(a.json, 'w') as f:
            json.dump({'cpu': model, 'torch': torch.__version__, 'threads': a.threads, 'ms': res}, f, indent=1)


def cmd_fixture(a):
    """A small deterministic case for the Rust test: weights, one frame's
    tensors and the float64 outputs of the network and the filter."""
    from safetensors.numpy import save_file
    os.makedirs(a.output, exist_ok=True)
    torch.manual_seed(1234)
    h, w = 13, 17
    g = torch.Generator().manual_seed(99)
    x = torch.rand(1, 10, h, w, generator=g, dtype=torch.float64)
    c = torch.rand(1, 3, h, w, generator=g, dtype=torch.float64) * 4
    alb = torch.rand(1, 3, h, w, generator=g, dtype=torch.float64) * 0.9 + 0.1
    t = {'x': x[0].float().numpy(), 'c': c[0].float().numpy(), 'albedo': alb[0].float().numpy()}
    for layers in (3, 6):
        net = ImportanceNet(layers)
        with torch.no_grad():
            # Scaled so the logits span several nats (windows far from uniform).
            for p in net.parameters():
                p.mul_(2.2 if layers == 3 else 1.6)
        path = os.path.join(a.output, 'wskp%d.safetensors' % layers)
        save_weights(net, path, layers)
        save_weights(net, os.path.join(a.output, 'wskp%d_merged.safetensors' % layers), layers, form='merged')
        # f64 from the f32 weights and inputs as stored.
        net64 = ImportanceNet(layers).double()
        load_weights(net64, path)
        xin = torch.from_numpy(t['x']).double()[None]
        with torch.no_grad():
            lg = net64(xin)
            lm = MergedNet(net64)(xin)
            assert torch.allclose(lg, lm, atol=1e-10), 'merged and unmerged nets differ'
            out = fused_filter(lg, torch.from_numpy(t['c']).double()[None], torch.from_numpy(t['albedo']).double()[None])
        t['logits%d' % layers] = lg[0].float().numpy()
        t['out%d' % layers] = out[0].float().numpy()
        print('WSKP-%d logits span %.2f .. %.2f' % (layers, lg.min().item(), lg.max().item()))
    save_file(t, os.path.join(a.output, 'case.safetensors'), metadata={'made_by': 'tools/torch_wskp.py fixture', 'torch': torch.__version__})
    print('wrote the fixture to %s' % a.output)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest='cmd', required=True)
    t = sub.add_parser('train')
    t.add_argument('--data', required=True)
    t.add_argument('--val')
    t.add_argument('--minutes', type=float, default=20)
    t.add_argument('--layers', type=int, default=6)
    t.add_argument('--batch', type=int, default=8)
    t.add_argument('--crop', type=int, default=64)
    t.add_argument('--lr', type=float, default=1e-3)
    t.add_argument('--threads', type=int, default=2)
    t.add_argument('--seed', type=int, default=1)
    t.add_argument('-o', '--output', required=True)
    d = sub.add_parser('denoise')
    d.add_argument('--weights', required=True)
    d.add_argument('--layers', type=int, default=6)
    d.add_argument('--threads', type=int, default=2)
    d.add_argument('input')
    d.add_argument('-o', '--output', required=True)
    m = sub.add_parser('time')
    m.add_argument('--threads', type=int, default=2)
    m.add_argument('--reps', type=int, default=20)
    m.add_argument('--json')
    f = sub.add_parser('fixture')
    f.add_argument('-o', '--output', required=True)
    a = p.parse_args()
    {'train': cmd_train, 'denoise': cmd_denoise, 'time': cmd_time, 'fixture': cmd_fixture}[a.cmd](a)


if __name__ == '__main__':
    main()
