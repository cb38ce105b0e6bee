#!/usr/bin/env python3
"""WSKP (weight-sharing kernel prediction denoising) in PyTorch: the peer the
Rust implementation is compared with. It follows the contract of
tools/README.md ("PyTorch and OIDN peers"): the same inputs, ImportanceNet
(training-time 5x5 + 3x3 + 1x1 branches, identity on the middle layers,
merged into one 5x5 conv for inference), fused filter, SMAPE loss and
safetensors layout as the Rust side.

    torch_wskp.py train --data DIR [--val DIR] --minutes M -o W.safetensors
                        [--threads 2 --batch 8 --crop 64 --layers 6 --seed S]
    torch_wskp.py denoise --weights W [--layers L] IN_DIR -o OUT_DIR
    torch_wskp.py evaluate --weights W --data DIR -o OUT   (scores per sequence)
    torch_wskp.py time [--threads 2]
    torch_wskp.py fixture -o tests/fixtures/wskp_torch

The temporally accumulated radiance comes from `mcdenoise denoise --method
ta` ($MCDENOISE, default /work/bin/mcdenoise), run once per sequence into a
temporary directory.
"""
import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

# On a machine shared with other jobs, OpenMP's default spin-waiting stalls
# every parallel region whose partner thread is descheduled (measured here:
# the WSKP-6 forward of a 8x64x64 batch took 0.9 s on 2 threads under load,
# 0.06 s with passive waiting). Set OMP_WAIT_POLICY=ACTIVE to override.
os.environ.setdefault('OMP_WAIT_POLICY', 'PASSIVE')
import torch  # noqa: E402
import torch.nn.functional as F

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import exrio  # noqa: E402

EPS = 0.01
SIZES = (3, 5, 7, 9, 11, 13)
SMAPE_EPS = 0.01
FORMAT = 'mcdenoise-wskp'


def mcdenoise_bin():
    return os.environ.get('MCDENOISE', '/work/bin/mcdenoise')


# ----------------------------------------------------------------------------
# The network

def layer_shapes(layers):
    """(cin, cout) of each layer of the L-layer ImportanceNet."""
    if layers == 6:
        return [(10, 14)] + [(14, 14)] * 4 + [(14, 12)]
    if layers == 3:
        return [(10, 14), (14, 14), (14, 12)]
    raise SystemExit('--layers must be 3 or 6, not %r' % layers)


class RepLayer(torch.nn.Module):
    """One training-time layer: 5x5 (pad 2) + 3x3 (pad 1) + 1x1 convolutions,
    no bias, plus the identity when the channel counts are equal."""

    def __init__(self, cin, cout):
        super().__init__()
        self.conv5 = torch.nn.Conv2d(cin, cout, 5, padding=2, bias=False)
        self.conv3 = torch.nn.Conv2d(cin, cout, 3, padding=1, bias=False)
        self.conv1 = torch.nn.Conv2d(cin, cout, 1, padding=0, bias=False)
        self.identity = cin == cout

    def forward(self, x):
        y = self.conv5(x) + self.conv3(x) + self.conv1(x)
        if self.identity:
            y = y + x
        return y

    def merged_weight(self):
        """The single 5x5 kernel [cout, cin, 5, 5] computing the same layer."""
        w = self.conv5.weight.detach().clone()
        w[:, :, 1:4, 1:4] += self.conv3.weight.detach()
        w[:, :, 2, 2] += self.conv1.weight.detach()[:, :, 0, 0]
        if self.identity:
            idx = torch.arange(w.shape[0])
            w[idx, idx, 2, 2] += 1.0
        return w


class ImportanceNet(torch.nn.Module):
    """Training form. state_dict() names are the weights file's names
    (layers.{i}.conv5.weight, ...)."""

    def __init__(self, layers):
        super().__init__()
        self.n_layers = layers
        self.layers = torch.nn.ModuleList([RepLayer(a, b) for a, b in layer_shapes(layers)])

    def forward(self, x):
        last = len(self.layers) - 1
        for i, layer in enumerate(self.layers):
            x = layer(x)
            if i < last:
                x = F.leaky_relu(x, 0.1)
        return x

    def merged(self):
        return [layer.merged_weight() for layer in self.layers]


def run_merged(weights, x):
    """Inference form: one 5x5 convolution (zero padding 2) per layer."""
    last = len(weights) - 1
    for i, w in enumerate(weights):
        x = F.conv2d(x, w, padding=2)
        if i < last:
            x = F.leaky_relu(x, 0.1)
    return x


# ----------------------------------------------------------------------------
# The filter and the loss

def fused_filter(logits, c, alb):
    """out(p) = alb(p) * sum_k alpha_k(p) * sum_q e_k(q) c(q) / sum_q e_k(q).

    logits [B,12,H,W]: channels 0..5 importance I_k for k in SIZES, 6..11
    fusion logits; c [B,3,H,W] demodulated irradiance; alb [B,3,H,W] the
    remodulation factor a + EPS. q runs over the k x k window around p,
    out-of-image q excluded: zero padding of both sums (avg_pool2d counting
    the padding divides numerator and denominator by the same k*k). Since
    e_k depends on q only, both sums are box filters (separable).

    e_k = exp(I_k - m_k) with m_k the maximum of I_k over each image (detached;
    it cancels exactly). A window whose every weight underflows (its logits
    all more than ~87 nats under m_k in f32, ~708 in f64) has a zero
    denominator; it is guarded to give 0 rather than NaN. Run in float64
    (denoise does) to push that limit out of reach.
    """
    imp, fus = logits[:, :6], logits[:, 6:12]
    alpha = torch.softmax(fus, dim=1)
    m = imp.detach().amax(dim=(2, 3), keepdim=True)
    e = torch.exp(imp - m)
    tiny = torch.finfo(logits.dtype).tiny
    out = torch.zeros_like(c)
    for i, k in enumerate(SIZES):
        ek = e[:, i:i + 1]
        r = k // 2
        # numerator (3 channels) and denominator together; the k x k box
        # as a k x 1 then a 1 x k box (both zero-padded: exact).
        s = torch.cat([ek * c, ek], 1)
        s = F.avg_pool2d(s, (k, 1), stride=1, padding=(r, 0), count_include_pad=True)
        s = F.avg_pool2d(s, (1, k), stride=1, padding=(0, r), count_include_pad=True)
        out = out + alpha[:, i:i + 1] * (s[:, :3] / s[:, 3:].clamp_min(tiny))
    return alb * out


def fused_filter_direct(logits, c, alb):
    """The same filter window by window, each window shifted by its own
    maximum (float64 numpy loops; small images only: the fixture's check)."""
    lg = np.asarray(logits, dtype=np.float64)
    c = np.asarray(c, dtype=np.float64)
    alb = np.asarray(alb, dtype=np.float64)
    _, h, w = lg.shape
    f = lg[6:12] - lg[6:12].max(axis=0)
    alpha = np.exp(f) / np.exp(f).sum(axis=0)
    out = np.zeros((3, h, w))
    for i, k in enumerate(SIZES):
        r = k // 2
        for y in range(h):
            for x in range(w):
                y0, y1, x0, x1 = max(0, y - r), min(h, y + r + 1), max(0, x - r), min(w, x + r + 1)
                li = lg[i, y0:y1, x0:x1]
                e = np.exp(li - li.max())
                cw = c[:, y0:y1, x0:x1]
                out[:, y, x] += alpha[i, y, x] * (e * cw).sum(axis=(1, 2)) / e.sum()
    return alb * out


def smape(out, ref):
    return (torch.abs(out - ref) / (torch.abs(out) + torch.abs(ref) + SMAPE_EPS)).mean()


# ----------------------------------------------------------------------------
# Inputs

def frame_inputs(t, a, n, d):
    """Network input x [10,H,W], demodulated irradiance c [3,H,W] and the
    remodulation factor a + EPS [3,H,W], all float32, from the accumulated
    radiance t [3,H,W], albedo a [3,H,W], normal n [3,H,W] and depth d [H,W]
    of one whole frame (the depth range is the frame's)."""
    t = np.asarray(t, dtype=np.float64)
    a = np.asarray(a, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    lo, hi = d.min(), d.max()
    dn = (d - lo) / (hi - lo) if hi > lo else np.zeros_like(d)
    x = np.concatenate([np.clip(t, 0.0, 1.0) ** (1 / 2.2), a, np.asarray(n) * 0.5 + 0.5, dn[None]])
    alb = a + EPS
    return x.astype(np.float32), (t / alb).astype(np.float32), alb.astype(np.float32)


def rgb(ch, prefix=''):
    return np.stack([ch[prefix + 'R'], ch[prefix + 'G'], ch[prefix + 'B']])


def frame_names(seq_dir):
    return sorted(f for f in os.listdir(seq_dir) if f.startswith('frame_') and f.endswith('.exr'))


def load_sequence(seq_dir, tmp, need_ref=False, ta_dir=None):
    """[(name, x, c, alb, ref or None)] of every frame of one sequence (the
    accumulated radiance written to ta_dir, default a new one under tmp)."""
    ta_dir = ta_dir or os.path.join(tmp, 'ta_%d' % len(os.listdir(tmp)))
    r = subprocess.run([mcdenoise_bin(), 'denoise', '--method', 'ta', seq_dir, '-o', ta_dir],
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit('mcdenoise denoise --method ta %s failed:\n%s' % (seq_dir, r.stderr))
    frames = []
    for name in frame_names(seq_dir):
        ref_path = os.path.join(seq_dir, 'ref', name)
        if need_ref and not os.path.exists(ref_path):
            print('  %s: no reference, skipped' % os.path.join(seq_dir, name))
            continue
        ch = exrio.read_exr(os.path.join(seq_dir, name))
        ta = exrio.read_exr(os.path.join(ta_dir, name))
        n = np.stack([ch['normal.X'], ch['normal.Y'], ch['normal.Z']])
        x, c, alb = frame_inputs(rgb(ta), rgb(ch, 'albedo.'), n, ch['depth.Z'])
        ref = rgb(exrio.read_exr(ref_path)).astype(np.float32) if os.path.exists(ref_path) else None
        frames.append((name, x, c, alb, ref))
    return frames


def sequence_dirs(root):
    """root itself if it holds frames, else its sub-directories that do."""
    if frame_names(root):
        return [root]
    subs = [os.path.join(root, s) for s in sorted(os.listdir(root))]
    return [s for s in subs if os.path.isdir(s) and frame_names(s)]


# ----------------------------------------------------------------------------
# Weights files

def write_safetensors(path, tensors, meta):
    """A safetensors file with its header in a fixed order (metadata, then
    tensors by name), so the same tensors always give the same bytes (the
    safetensors package orders the metadata at random). f32, little endian."""
    import json
    header = {'__metadata__': dict(sorted(meta.items()))}
    blobs, offset = [], 0
    for name in sorted(tensors):
        arr = np.ascontiguousarray(np.asarray(tensors[name], dtype='<f4'))
        blob = arr.tobytes()
        header[name] = {'dtype': 'F32', 'shape': list(arr.shape), 'data_offsets': [offset, offset + len(blob)]}
        blobs.append(blob)
        offset += len(blob)
    text = json.dumps(header, separators=(',', ':')).encode()
    text += b' ' * (-len(text) % 8)
    with open(path, 'wb') as f:
        f.write(len(text).to_bytes(8, 'little'))
        f.write(text)
        for blob in blobs:
            f.write(blob)


def save_weights(net, path, form='branches'):
    """The weights file of the contract: f32 [cout][cin][kh][kw]."""
    if form == 'branches':
        tensors = {name: p.detach().cpu().numpy() for name, p in net.state_dict().items()}
    elif form == 'merged':
        tensors = {'layers.%d.weight' % i: w.cpu().numpy() for i, w in enumerate(net.merged())}
    else:
        raise ValueError(form)
    meta = {'format': FORMAT, 'version': '1', 'layers': str(net.n_layers), 'form': form}
    write_safetensors(path, tensors, meta)


def read_weights(path):
    """(metadata, {name: float32 tensor})."""
    from safetensors import safe_open
    with safe_open(path, framework='pt') as f:
        meta = f.metadata() or {}
        tensors = {k: f.get_tensor(k) for k in f.keys()}
    if meta.get('format') != FORMAT:
        raise SystemExit('%s: metadata format %r, expected %r' % (path, meta.get('format'), FORMAT))
    return meta, tensors


def load_branches(path, layers=None, dtype=torch.float32):
    meta, t = read_weights(path)
    if meta.get('form') != 'branches':
        raise SystemExit('%s: form %r, expected branches' % (path, meta.get('form')))
    layers = layers or int(meta['layers'])
    if int(meta['layers']) != layers:
        raise SystemExit('%s holds %s layers, not %d' % (path, meta['layers'], layers))
    net = ImportanceNet(layers).to(dtype)
    net.load_state_dict({k: v.to(dtype) for k, v in t.items()}, strict=True)
    return net


def load_inference(path, layers=None, dtype=torch.float32):
    """Merged 5x5 kernels of either form of file."""
    meta, t = read_weights(path)
    n = int(meta['layers'])
    if layers and layers != n:
        raise SystemExit('%s holds %d layers, not %d' % (path, n, layers))
    if meta.get('form') == 'merged':
        ws = [t['layers.%d.weight' % i].to(dtype) for i in range(n)]
        for w, (cin, cout) in zip(ws, layer_shapes(n)):
            assert tuple(w.shape) == (cout, cin, 5, 5), w.shape
        return ws
    return load_branches(path, n, dtype).merged()


# ----------------------------------------------------------------------------
# train

def psnr(out, ref):
    """mcdenoise score's PSNR: on clamp(x, 0, 1)^(1/2.2), peak 1."""
    a = np.clip(out, 0, 1) ** (1 / 2.2)
    b = np.clip(ref, 0, 1) ** (1 / 2.2)
    mse = float(np.mean((a - b) ** 2))
    return 10 * np.log10(1.0 / max(mse, 1e-20))


@torch.no_grad()
def denoise_frames(weights, frames):
    """Network in f32 (merged form), filter in f64."""
    outs = []
    for name, x, c, alb, ref in frames:
        lg = run_merged(weights, torch.from_numpy(x)[None])
        o = fused_filter(lg.double(), torch.from_numpy(c)[None].double(), torch.from_numpy(alb)[None].double())
        outs.append((name, o[0].float().numpy(), ref))
    return outs


def validate(net, seqs):
    ws = net.merged()
    ps = [psnr(o, r) for frames in seqs for _, o, r in denoise_frames(ws, frames) if r is not None]
    return float(np.mean(ps)) if ps else float('nan')


def random_batch(rng, frames, batch, crop):
    """A batch of random crops, each under one of the 8 flips / 90-degree turns
    applied alike to every buffer (channel values untouched)."""
    cols = [[], [], [], []]
    for _ in range(batch):
        _, x, c, alb, ref = frames[rng.integers(len(frames))]
        h, w = x.shape[1:]
        y0, x0 = rng.integers(h - crop + 1), rng.integers(w - crop + 1)
        turn = rng.integers(8)
        for col, v in zip(cols, (x, c, alb, ref)):
            v = v[:, y0:y0 + crop, x0:x0 + crop]
            if turn & 1:
                v = v[:, :, ::-1]
            if turn & 2:
                v = v[:, ::-1, :]
            if turn & 4:
                v = v.transpose(0, 2, 1)
            col.append(np.ascontiguousarray(v))
    return [torch.from_numpy(np.stack(col)) for col in cols]


def train_step(net, opt, x, c, alb, ref):
    """One Adam step. The network runs in f32; the filter and the loss in the
    dtype of c, alb and ref (f64 in training: no window underflows)."""
    out = fused_filter(net(x).to(c.dtype), c, alb)
    loss = smape(out, ref)
    opt.zero_grad(set_to_none=True)
    loss.backward()
    opt.step()
    return loss


def cmd_train(a):
    torch.set_num_threads(a.threads)
    torch.manual_seed(a.seed)
    rng = np.random.default_rng(a.seed)
    with tempfile.TemporaryDirectory() as tmp:
        seqs = sequence_dirs(a.data)
        if not seqs:
            raise SystemExit('no sequence under %s' % a.data)
        frames = []
        for s in seqs:
            frames += load_sequence(s, tmp, need_ref=True)
        val = [load_sequence(s, tmp, need_ref=True) for s in sequence_dirs(a.val)] if a.val else []
    small = [f[0] for f in frames if min(f[1].shape[1:]) < a.crop]
    if small:
        raise SystemExit('frames smaller than the crop %d' % a.crop)
    print('training WSKP-%d on %d frames of %d sequences (%s); batch %d of %dx%d crops, Adam lr %g, '
          '%d threads, seed %d, %.1f minutes; network f32, filter and loss f64'
          % (a.layers, len(frames), len(seqs), a.data, a.batch, a.crop, a.crop, a.lr, a.threads, a.seed, a.minutes),
          flush=True)
    net = ImportanceNet(a.layers)
    opt = torch.optim.Adam(net.parameters(), lr=a.lr)
    budget = a.minutes * 60.0
    trained = 0.0  # seconds spent in training steps (validation excluded)
    step, window = 0, []
    while trained < budget:
        t0 = time.perf_counter()
        x, c, alb, ref = random_batch(rng, frames, a.batch, a.crop)
        loss = train_step(net, opt, x, c.double(), alb.double(), ref.double())
        trained += time.perf_counter() - t0
        step += 1
        window.append(loss.item())
        if step % a.print_every == 0:
            msg = 'step %6d  %7.1f s  loss %.4f  %.2f steps/s' % (step, trained, np.mean(window), step / trained)
            window = []
            if val and step % (a.print_every * a.val_every) == 0:
                msg += '  val PSNR %.2f dB' % validate(net, val)
            print(msg, flush=True)
    save_weights(net, a.output, 'branches')
    print('trained %d steps in %.1f s (%.2f steps/s); weights (branches form) in %s'
          % (step, trained, step / trained, a.output))
    if a.merged:
        save_weights(net, a.merged, 'merged')
        print('merged form in %s' % a.merged)
    if val:
        print('validation PSNR %.2f dB' % validate(net, val))


# ----------------------------------------------------------------------------
# denoise

def write_rgb(path, img):
    import OpenEXR
    chans = {name: np.ascontiguousarray(img[i], dtype=np.float32) for i, name in enumerate('RGB')}
    header = {'compression': OpenEXR.ZIP_COMPRESSION, 'type': OpenEXR.scanlineimage}
    with OpenEXR.File(header, chans) as f:
        f.write(path)


def cmd_denoise(a):
    torch.set_num_threads(a.threads)
    weights = load_inference(a.weights, a.layers)
    with tempfile.TemporaryDirectory() as tmp:
        frames = load_sequence(a.input, tmp)
    os.makedirs(a.output, exist_ok=True)
    ps = []
    for name, o, ref in denoise_frames(weights, frames):
        write_rgb(os.path.join(a.output, name), o)
        if ref is not None:
            ps.append(psnr(o, ref))
    msg = 'wrote %d frames to %s' % (len(frames), a.output)
    if ps:
        msg += ' (mean PSNR %.2f dB)' % np.mean(ps)
    print(msg)


# ----------------------------------------------------------------------------
# evaluate

def score(ref_dir, out_dir):
    """mcdenoise score's mean PSNR and SSIM of out_dir against ref_dir."""
    r = subprocess.run([mcdenoise_bin(), 'score', '--reference', ref_dir, out_dir, '--json'],
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit('mcdenoise score %s failed:\n%s' % (out_dir, r.stderr))
    import json
    mean = json.loads(r.stdout)['mean']
    return mean['psnr'], mean['ssim']


def cmd_evaluate(a):
    """Denoise every sequence under --data into OUT/wskp/SEQ (TA into
    OUT/ta/SEQ) and score the 1-spp input, TA and WSKP against SEQ/ref."""
    torch.set_num_threads(a.threads)
    weights = load_inference(a.weights, a.layers)
    print('| sequence | frames | input PSNR / SSIM | TA PSNR / SSIM | WSKP PSNR / SSIM | WSKP gain over input |')
    print('| --- | --- | --- | --- | --- | --- |')
    gains = []
    for seq in sequence_dirs(a.data):
        name = os.path.basename(os.path.normpath(seq))
        ta_dir = os.path.join(a.output, 'ta', name)
        out_dir = os.path.join(a.output, 'wskp', name)
        os.makedirs(out_dir, exist_ok=True)
        frames = load_sequence(seq, None, ta_dir=ta_dir)
        for fname, o, _ in denoise_frames(weights, frames):
            write_rgb(os.path.join(out_dir, fname), o)
        ref = os.path.join(seq, 'ref')
        (pi, si), (pt, st), (pw, sw) = score(ref, seq), score(ref, ta_dir), score(ref, out_dir)
        gains.append(pw - pi)
        print('| %s | %d | %.2f dB / %.4f | %.2f dB / %.4f | %.2f dB / %.4f | %+.2f dB |'
              % (name, len(frames), pi, si, pt, st, pw, sw, pw - pi), flush=True)
    print('mean gain %+.2f dB over %d sequences' % (np.mean(gains), len(gains)))


# ----------------------------------------------------------------------------
# time

def median_ms(fn, reps, warmup=3):
    """(median wall ms, min wall ms) of reps calls after warmup calls; the
    process CPU time per call (all threads) is kept in median_ms.cpu."""
    for _ in range(warmup):
        fn()
    ts = []
    c0 = time.process_time()
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        ts.append((time.perf_counter() - t0) * 1e3)
    median_ms.cpu = (time.process_time() - c0) * 1e3 / reps
    return statistics.median(ts), min(ts)


def cpu_model():
    out = subprocess.run(['lscpu'], capture_output=True, text=True).stdout
    for line in out.splitlines():
        if line.startswith('Model name'):
            return line.split(':', 1)[1].strip()
    return '?'


def cmd_time(a):
    torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    print('CPU: %s; %d logical CPUs; load average %s' % (cpu_model(), os.cpu_count(),
                                                       ' '.join('%.2f' % v for v in os.getloadavg())))
    print('torch %s, intra-op threads %d, inter-op threads %d, mkldnn %s, OMP_WAIT_POLICY=%s'
          % (torch.__version__, torch.get_num_threads(), torch.get_num_interop_threads(),
             torch.backends.mkldnn.is_available(), os.environ.get('OMP_WAIT_POLICY')))
    # (a) one eager training step of WSKP-6, batch 8 of 128x128 crops.
    b, s = 8, 128
    g = torch.Generator().manual_seed(1)
    x = torch.rand(b, 10, s, s, generator=g)
    alb = torch.rand(b, 3, s, s, generator=g) + EPS
    c = torch.rand(b, 3, s, s, generator=g) * 2
    ref = torch.rand(b, 3, s, s, generator=g) * 2
    for dt in ((torch.float32,) if a.train_only else (torch.float64, torch.float32)):
        net = ImportanceNet(6)
        opt = torch.optim.Adam(net.parameters(), lr=1e-3)
        cd, ad, rd = c.to(dt), alb.to(dt), ref.to(dt)
        med, best = median_ms(lambda: train_step(net, opt, x, cd, ad, rd), a.reps)
        print('train step WSKP-6, batch 8 of 128x128 (forward, SMAPE, backward, Adam; network f32, filter %s%s): '
              'median %.1f ms (min %.1f) of %d; CPU %.0f ms/run'
              % (str(dt)[6:], ' as `train` runs it' if dt == torch.float64 else '', med, best, a.reps, median_ms.cpu))
    if a.train_only:
        return
    # (b) inference at 1280x720: merged networks, filter, and both together.
    h, w = 720, 1280
    x = torch.rand(1, 10, h, w, generator=g)
    c = torch.rand(1, 3, h, w, generator=g) * 2
    alb = torch.rand(1, 3, h, w, generator=g) + EPS
    with torch.no_grad():
        for layers in (6, 3):
            ws = ImportanceNet(layers).merged()
            med, best = median_ms(lambda: run_merged(ws, x), a.infer_reps)
            print('inference 1280x720, WSKP-%d merged network: median %.1f ms (min %.1f) of %d; CPU %.0f ms/run'
                  % (layers, med, best, a.infer_reps, median_ms.cpu))
            cl = torch.channels_last
            xl, wl = x.contiguous(memory_format=cl), [v.contiguous(memory_format=cl) for v in ws]
            med, best = median_ms(lambda: run_merged(wl, xl), a.infer_reps)
            print('inference 1280x720, WSKP-%d merged network, channels-last tensors: median %.1f ms (min %.1f) of %d; CPU %.0f ms/run'
                  % (layers, med, best, a.infer_reps, median_ms.cpu))
            lg = run_merged(ws, x)
            if layers == 6:
                med, best = median_ms(lambda: fused_filter(lg, c, alb), a.infer_reps)
                print('inference 1280x720, fused filter (6 sizes, f32): median %.1f ms (min %.1f) of %d; CPU %.0f ms/run'
                      % (med, best, a.infer_reps, median_ms.cpu))
            med, best = median_ms(lambda: fused_filter(run_merged(ws, x), c, alb), a.infer_reps)
            print('inference 1280x720, WSKP-%d network + filter: median %.1f ms (min %.1f) of %d; CPU %.0f ms/run'
                  % (layers, med, best, a.infer_reps, median_ms.cpu))
            med, best = median_ms(lambda: fused_filter(run_merged(wl, xl).contiguous(), c, alb), a.infer_reps)
            print('inference 1280x720, WSKP-%d network (channels-last) + filter: median %.1f ms (min %.1f) of %d; CPU %.0f ms/run'
                  % (layers, med, best, a.infer_reps, median_ms.cpu))
    print('load average after: %s' % ' '.join('%.2f' % v for v in os.getloadavg()))


# ----------------------------------------------------------------------------
# fixture

def fixture_frame(h, w, rng):
    """A plausible small frame: two surfaces meeting at a slanted edge, with
    textures, a shadow, 1-spp-like accumulated radiance and a few fireflies."""
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    wall = (xx + 0.6 * yy) > 0.55 * w + 3
    # albedo: a checker on the floor, a smooth colour on the wall, one black pixel.
    a = np.where(wall, np.array([0.7, 0.55, 0.3])[:, None, None],
                 np.where(((xx // 3 + yy // 3) % 2)[None] > 0, 0.8, 0.15) * np.ones((3, 1, 1)))
    a = np.clip(a + rng.uniform(-0.05, 0.05, a.shape), 0.0, 1.0)
    a[:, h // 2, w // 3] = 0.0
    # normals: two tilted planes, unit length, with some bump.
    n = np.where(wall, np.array([-0.8, 0.1, 0.59])[:, None, None], np.array([0.05, 0.99, 0.1])[:, None, None])
    n = n + rng.normal(0, 0.05, n.shape)
    n /= np.linalg.norm(n, axis=0, keepdims=True)
    d = np.where(wall, 4.0 + 0.05 * xx, 2.0 + 0.2 * yy) + rng.uniform(0, 0.01, (h, w))
    # irradiance: a soft shadow, noise of ~ one accumulated sample, fireflies.
    irr = 1.5 * (1.0 - 0.7 * np.exp(-((xx - 5) ** 2 + (yy - 8) ** 2) / 8.0))
    irr = irr[None] * rng.gamma(2.0, 0.5, (3, h, w))
    irr[:, 2, 12] *= 40.0
    irr[1, 9, 4] *= 25.0
    t = a * irr
    return t, a, n, d


def scale_last_layer(net, x, span=10.0):
    """Scale the last layer (no activation after it, no identity) so the
    largest |logit| on x is `span`."""
    with torch.no_grad():
        peak = net(x).abs().max().item()
        last = net.layers[-1]
        for conv in (last.conv5, last.conv3, last.conv1):
            conv.weight.mul_(span / peak)


def cmd_fixture(a):
    os.makedirs(a.output, exist_ok=True)
    h, w = 13, 17
    rng = np.random.default_rng(2024)
    t, alb_raw, n, d = fixture_frame(h, w, rng)
    x, c, alb = frame_inputs(t, alb_raw, n, d)
    case = {
        'x': x, 'c': c, 'a': alb_raw.astype(np.float32), 'albedo': alb,
        't': t.astype(np.float32), 'normal': n.astype(np.float32), 'depth': d[None].astype(np.float32),
    }
    # The f64 computations below start from these f32 values as stored.
    x64 = torch.from_numpy(x).double()[None]
    c64 = torch.from_numpy(c).double()[None]
    alb64 = torch.from_numpy(alb).double()[None]
    for layers, seed in ((3, 3), (6, 6)):
        torch.manual_seed(seed)
        net = ImportanceNet(layers).double()
        scale_last_layer(net, x64)
        branches = os.path.join(a.output, 'wskp%d.safetensors' % layers)
        merged = os.path.join(a.output, 'wskp%d_merged.safetensors' % layers)
        save_weights(net, branches, 'branches')
        save_weights(net, merged, 'merged')
        # Expected values: the stored f32 branch weights, in float64.
        net64 = load_branches(branches, layers, torch.float64)
        with torch.no_grad():
            lg = net64(x64)
            out = fused_filter(lg, c64, alb64)
            # Checks: the merged form (merged in f64, and the merged file) and
            # the direct per-window filter give the same results.
            lg_m = run_merged(net64.merged(), x64)
            lg_f = run_merged(load_inference(merged, layers, torch.float64), x64)
            out_m = fused_filter(lg_m, c64, alb64)
        peak = lg.abs().max().item()
        e1 = (lg - lg_m).abs().max().item()
        e2 = (lg - lg_f).abs().max().item()
        e3 = (out - out_m).abs().max().item()
        direct = fused_filter_direct(lg[0].numpy(), c64[0].numpy(), alb64[0].numpy())
        e4 = float(np.abs(direct - out[0].numpy()).max())
        print('WSKP-%d: logits %.2f .. %.2f (importance %.2f .. %.2f, fusion %.2f .. %.2f); output %.3f .. %.3f'
              % (layers, lg.min().item(), lg.max().item(), lg[:, :6].min().item(), lg[:, :6].max().item(),
                 lg[:, 6:].min().item(), lg[:, 6:].max().item(), out.min().item(), out.max().item()))
        print('  max |difference|: merged (f64) logits %.1e, merged file (f32 weights) logits %.1e, '
              'merged filter output %.1e, direct per-window filter %.1e' % (e1, e2, e3, e4))
        assert e1 <= 1e-12 * peak, 'merged and unmerged networks differ'
        assert e2 <= 1e-5 * peak, 'the merged file differs from the branches file'
        assert e3 <= 1e-10 * (1 + out.abs().max().item()), 'merged and unmerged outputs differ'
        assert e4 <= 1e-10 * (1 + out.abs().max().item()), 'box-sum filter and direct filter differ'
        case['logits%d' % layers] = lg[0].float().numpy()
        case['out%d' % layers] = out[0].float().numpy()
    meta = {'made_by': 'tools/torch_wskp.py fixture -o tests/fixtures/wskp_torch', 'torch': torch.__version__,
            'numpy': np.__version__, 'eps': str(EPS), 'sizes': ','.join(map(str, SIZES))}
    write_safetensors(os.path.join(a.output, 'case.safetensors'), case, meta)
    print('wrote %s' % a.output)


# ----------------------------------------------------------------------------

def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest='cmd', required=True)
    t = sub.add_parser('train', help='train on every sequence under --data')
    t.add_argument('--data', required=True)
    t.add_argument('--val')
    t.add_argument('--minutes', type=float, required=True, help='training time (validation excluded)')
    t.add_argument('--threads', type=int, default=2)
    t.add_argument('--batch', type=int, default=8)
    t.add_argument('--crop', type=int, default=64)
    t.add_argument('--layers', type=int, default=6, choices=[3, 6])
    t.add_argument('--lr', type=float, default=1e-3)
    t.add_argument('--seed', type=int, default=1)
    t.add_argument('--print-every', type=int, default=100)
    t.add_argument('--val-every', type=int, default=10, help='validate every N prints')
    t.add_argument('--merged', help='also write the merged form here')
    t.add_argument('-o', '--output', required=True)
    d = sub.add_parser('denoise', help='denoise one sequence directory')
    d.add_argument('--weights', required=True)
    d.add_argument('--layers', type=int, choices=[3, 6])
    d.add_argument('--threads', type=int, default=2)
    d.add_argument('input')
    d.add_argument('-o', '--output', required=True)
    e = sub.add_parser('evaluate', help='denoise and score every sequence under --data')
    e.add_argument('--weights', required=True)
    e.add_argument('--layers', type=int, choices=[3, 6])
    e.add_argument('--threads', type=int, default=2)
    e.add_argument('--data', required=True)
    e.add_argument('-o', '--output', required=True, help='outputs go to OUT/ta/SEQ and OUT/wskp/SEQ')
    m = sub.add_parser('time', help='training-step and 1280x720 inference times')
    m.add_argument('--threads', type=int, default=2)
    m.add_argument('--reps', type=int, default=20)
    m.add_argument('--infer-reps', type=int, default=10)
    m.add_argument('--train-only', action='store_true', help='only the training step (f32 filter)')
    f = sub.add_parser('fixture', help='write the Rust test fixture')
    f.add_argument('-o', '--output', required=True)
    a = p.parse_args()
    {'train': cmd_train, 'denoise': cmd_denoise, 'evaluate': cmd_evaluate, 'time': cmd_time,
     'fixture': cmd_fixture}[a.cmd](a)


if __name__ == '__main__':
    main()
