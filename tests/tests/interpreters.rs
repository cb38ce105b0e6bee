//! The two graph interpreters agree. Training (`nn::Workspace::forward`:
//! every tensor of a crop kept in f32 for the backward pass) and inference
//! (`nn::infer::Inference`: only the tensors still to be read, in the
//! storage precision, streamed over bands) walk the same network
//! descriptions; they must give the same outputs for every network the
//! project has: WSKP with 3 and 6 layers, AFN's kernel predictor and its
//! refinement network, and the cross-regression U-Net. And AFN's streamed
//! inference (its full-scale head and the filters run in bands of rows)
//! must give the output of its training forward pass on the same frame.

use std::sync::Mutex;

use mcdenoise::io::frame::{Buffer, Frame};
use mcdenoise::methods::afn::{self, Variant};
use mcdenoise::methods::{cross, wskp, Denoiser, Timings};
use mcdenoise::nn::infer::Inference;
use mcdenoise::nn::loss::Loss;
use mcdenoise::nn::{Merged, Net, Trainer, Workspace};
use mcdenoise::runtime::par::Pool;
use mcdenoise::runtime::precision::Planes;
use mcdenoise::runtime::Ctx;
use mcdenoise_core::{Isa, F32};
use mcdenoise_tests::Img;

/// Largest `|a - b|` relative to the largest `|b|`.
fn rel_diff(a: &[f32], b: &[f32]) -> f64 {
    assert_eq!(a.len(), b.len());
    let peak = b.iter().fold(0.0f64, |m, &v| m.max(v.abs() as f64)).max(1e-30);
    a.iter().zip(b).map(|(&x, &y)| (x as f64 - y as f64).abs()).fold(0.0, f64::max) / peak
}

fn training_forward(net: &Net, params: &[f32], x: &[f32], w: usize, h: usize) -> Vec<f32> {
    let mut ws = Workspace::new(net, w, h);
    ws.input_mut().copy_from_slice(x);
    let mut m = Merged::new(net);
    m.update(net, params);
    ws.forward(net, &m, params, Isa::detect()).unwrap();
    ws.output().to_vec()
}

fn inference(net: &Net, params: &[f32], x: &[f32], w: usize, h: usize) -> Vec<f32> {
    let mut ctx = Ctx::new(2, Isa::detect()).unwrap();
    let mut inf = Inference::<F32>::new(net, params, None, None).unwrap();
    inf.run(&mut ctx, Planes::<f32>::from_vec(net.desc.cin, w, h, x.to_vec())).unwrap().data.to_vec()
}

#[test]
fn training_and_inference_agree_on_every_network() {
    let (w, h) = (36, 28);
    let nets: Vec<(&str, Net)> = vec![
        ("wskp-3", wskp::net(3).unwrap()),
        ("wskp-6", wskp::net(6).unwrap()),
        ("afn kernel predictor", afn::kernel_net().unwrap()),
        ("afn refinement", afn::refine_net().unwrap()),
        ("cross u-net", cross::net()),
    ];
    for (name, net) in nets {
        let params: Vec<f32> = net.init(11).iter().map(|v| v * 0.5).collect();
        let x = Img::random(net.desc.cin, w, h, -1.0, 1.0, 3).data;
        let a = training_forward(&net, &params, &x, w, h);
        let b = inference(&net, &params, &x, w, h);
        let d = rel_diff(&b, &a);
        assert!(a.iter().any(|v| v.abs() > 1e-3), "{name}: a non-trivial output");
        eprintln!("{name}: inference against training, largest difference {d:.2e} of the peak");
        assert!(d < 1e-5, "{name}: the interpreters differ by {d:e} of the output's peak");
    }
}

/// A frame with every buffer AFN reads, smooth enough to make sense.
fn frame(w: usize, h: usize) -> Frame {
    let n = w * h;
    let img = |c: usize, lo: f32, hi: f32, seed: u64| Img::random(c, w, h, lo, hi, seed).data;
    let mut f = Frame::from_color("afn.exr", w, h, img(3, 0.0, 2.0, 1)).unwrap();
    f.set(Buffer::Albedo, img(3, 0.05, 0.9, 2)).unwrap();
    let normal: Vec<f32> = (0..3 * n).map(|i| if i / n == 2 { 1.0 } else { 0.0 }).collect();
    f.set(Buffer::Normal, normal).unwrap();
    f.set(Buffer::Depth, img(1, 1.0, 3.0, 4)).unwrap();
    f.set(Buffer::Position, img(3, -1.0, 1.0, 5)).unwrap();
    f
}

#[test]
fn afn_streamed_inference_equals_its_training_forward() {
    let (w, h) = (52, 40);
    let n = w * h;
    let f = frame(w, h);
    let (kn, rn) = (afn::kernel_net().unwrap(), afn::refine_net().unwrap());
    let kp: Vec<f32> = kn.init(21);
    let rp: Vec<f32> = rn.init(22).iter().map(|v| v * 0.1).collect();
    for variant in [Variant::Fusion, Variant::TaOnly, Variant::OneSppOnly] {
        // Inference: the method itself on the sequence's first frame (its
        // temporal accumulation is the frame).
        let settings = mcdenoise::methods::Settings { threads: 2, ..Default::default() };
        let mut ctx = mcdenoise::methods::context(&settings).unwrap();
        // (Without the wide pass and the fallback to the input, which only
        // inference has.)
        let mut den = afn::Afn::<F32>::from_params(&f, (kp.clone(), rp.clone()), true, variant)
            .unwrap()
            .with_fallback(false)
            .with_wide(false);
        let out = den.denoise(&f, &mut ctx, &mut Timings::default()).unwrap();
        // Training: the same frame as one crop through the training head.
        let pool = Pool::new(2).unwrap();
        let colour = f.get(Buffer::Color).unwrap().to_vec();
        let mut x = vec![0.0f32; afn::CIN * n];
        let mut data = vec![0.0f32; afn::buf::DATA_PLANES * n];
        {
            let (c1, rest) = data.split_at_mut(3 * n);
            let (ct, rest) = rest.split_at_mut(3 * n);
            let (alb, rest) = rest.split_at_mut(3 * n);
            let (rf, rest) = rest.split_at_mut(3 * n);
            let (feats, rest) = rest.split_at_mut(7 * n);
            let (expo, ex) = rest.split_at_mut(n);
            let e = afn::inputs(&pool, variant, &f, &colour, &mut x, c1, ct, alb, ex).unwrap();
            rf.copy_from_slice(&colour);
            feats.copy_from_slice(&x[6 * n..]);
            expo.fill(e);
        }
        let mut tr =
            Trainer::with_nets(vec![(kn.clone(), kp.clone(), (w, h)), (rn.clone(), rp.clone(), (w, h))], 1, 1e-3, 0.0)
                .unwrap();
        for wss in tr.workspaces() {
            afn::crop_buffers(wss);
        }
        let got = Mutex::new(Vec::new());
        let fill = |_: usize, wss: &mut [Workspace]| {
            wss[0].input_mut().copy_from_slice(&x);
            wss[0].aux[afn::buf::DATA].copy_from_slice(&data);
            Ok(())
        };
        let head = |_: usize, nets: &mcdenoise::nn::Nets<'_>, wss: &mut [Workspace]| {
            let l = afn::head(nets, wss, Loss::RelMseN2n, 1.0, true, variant)?;
            *got.lock().unwrap() = wss[0].aux[afn::buf::OUT].clone();
            Ok(l)
        };
        tr.step(&pool, Isa::detect(), &fill, &head, false).unwrap();
        let train = got.into_inner().unwrap();
        assert!(train.len() == 3 * n && train.iter().any(|v| *v > 0.01), "{variant:?}: a non-trivial output");
        let d = rel_diff(&out, &train);
        eprintln!("{variant:?}: streamed inference against the training forward, {d:.2e} of the peak");
        assert!(d < 1e-4, "{variant:?}: AFN's inference differs from its training forward by {d:e}");
    }
}

/// The 8-bit emulation's weights: per output channel, 255 levels symmetric
/// about 0 whose step is the channel's largest magnitude over 127, each
/// weight moved by at most half a step, the largest kept.
#[test]
fn int8_weights_are_on_each_channels_grid() {
    let per = 9 * 5;
    let mut w: Vec<f32> = Img::random(1, per, 4, -0.7, 0.7, 21).data;
    // One channel of tiny weights, one of zeros: each has its own scale.
    w[per..2 * per].iter_mut().for_each(|v| *v *= 1e-4);
    w[2 * per..3 * per].iter_mut().for_each(|v| *v = 0.0);
    let orig = w.clone();
    mcdenoise::nn::infer::int8_weights(&mut w, per);
    for (ch, (q, o)) in w.chunks(per).zip(orig.chunks(per)).enumerate() {
        let m = o.iter().fold(0.0f64, |m, &v| m.max(v.abs() as f64));
        if m == 0.0 {
            assert!(q.iter().all(|&v| v == 0.0), "channel {ch}: zeros stay zeros");
            continue;
        }
        let step = m / 127.0;
        let qm = q.iter().fold(0.0f64, |a, &v| a.max(v.abs() as f64));
        assert!((qm - m).abs() <= 1e-6 * m, "channel {ch}: the largest weight is kept");
        for (&a, &b) in q.iter().zip(o) {
            let k = a as f64 / step;
            assert!((k - k.round()).abs() < 1e-3 && k.abs() <= 127.0 + 1e-3, "channel {ch}: {a} is not on the grid");
            assert!((a as f64 - b as f64).abs() <= 0.5 * step * (1.0 + 1e-4), "channel {ch}: {b} -> {a}");
        }
    }
}

/// The 8-bit emulation of a network: every tensor it rounds sits on its
/// grid (the output too when it is not kept), the output stays near f32's,
/// and fixed point refuses it.
#[test]
fn int8_emulation_rounds_every_tensor_to_its_grid() {
    let (w, h) = (36, 28);
    let mut ctx = Ctx::new(2, Isa::detect()).unwrap();
    for (name, net) in [("wskp-3", wskp::net(3).unwrap()), ("afn refinement", afn::refine_net().unwrap())] {
        let params: Vec<f32> = net.init(11).iter().map(|v| v * 0.5).collect();
        let x = Img::random(net.desc.cin, w, h, -1.0, 1.0, 3).data;
        let input = || Planes::<f32>::from_vec(net.desc.cin, w, h, x.clone());
        let mut f32net = Inference::<F32>::new(&net, &params, None, None).unwrap();
        let ranges = f32net.ranges(&mut ctx, input()).unwrap();
        let exact = f32net.run(&mut ctx, input()).unwrap().data.to_vec();
        // The output rounded too: its values are multiples of its step.
        let mut q = Inference::<F32>::new(&net, &params, None, None).unwrap();
        q.emulate_int8(&ranges, false).unwrap();
        let out = q.run(&mut ctx, input()).unwrap().data.to_vec();
        let step = *ranges.last().unwrap() as f64 / 127.0;
        let distinct: std::collections::BTreeSet<i64> = out
            .iter()
            .map(|&v| {
                let k = v as f64 / step;
                assert!(
                    (k - k.round()).abs() < 1e-3 && k.abs() <= 127.0 + 1e-3,
                    "{name}: {v} is off the output's grid"
                );
                k.round() as i64
            })
            .collect();
        assert!(distinct.len() > 10 && distinct.len() <= 255, "{name}: {} levels", distinct.len());
        // Kept: near the f32 output (8 bits per layer), but not equal.
        let mut k = Inference::<F32>::new(&net, &params, None, None).unwrap();
        k.emulate_int8(&ranges, true).unwrap();
        let kept = k.run(&mut ctx, input()).unwrap().data.to_vec();
        let d = rel_diff(&kept, &exact);
        eprintln!("{name}: 8-bit emulation against f32, largest difference {d:.2e} of the peak");
        assert!(d > 1e-5 && d < 0.1, "{name}: the emulation moved the output by {d:e} of its peak");
        let mut fx = Inference::<mcdenoise_core::Fixed>::new(&net, &params, Some(&ranges), None).unwrap();
        assert!(fx.emulate_int8(&ranges, true).is_err(), "{name}: fixed point refuses the emulation");
    }
}
