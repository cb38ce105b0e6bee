//! Network weights: the safetensors round trip, the RepVGG merge (the
//! branches summed equal the merged convolution), and bad weight files
//! (missing tensors, wrong shapes or dtype, NaN, truncation, another
//! network's file) giving an error that names the file and the tensor.

use mcdenoise::methods::wskp;
use mcdenoise::nn::weights::{save, save_params, File, Form, Tensor};
use mcdenoise::nn::{Conv, Layer, Net, NetDesc};
use mcdenoise_core::conv::{self, Activation, Conv2d};
use mcdenoise_core::{Isa, F32};
use mcdenoise_tests::Img;

fn tmp(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("mcdenoise-weights-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d.join(name)
}

#[test]
fn branches_and_merged_files_load_to_the_same_network() {
    let net = wskp::net(3).unwrap();
    let params = net.init(5);
    let (pb, pm) = (tmp("b.safetensors"), tmp("m.safetensors"));
    save_params(
        &pb,
        &net,
        &params,
        Form::Branches,
        "wskp",
        &[("layers", "3".into()), ("transform", mcdenoise::methods::features::TRANSFORM.into())],
    )
    .unwrap();
    save_params(
        &pm,
        &net,
        &params,
        Form::Merged,
        "wskp",
        &[("layers", "3".into()), ("transform", mcdenoise::methods::features::TRANSFORM.into())],
    )
    .unwrap();
    let back = File::read(&pb).unwrap().params(&net, "wskp", &[]).unwrap();
    assert_eq!(back, params, "branches round trip");
    let merged = File::read(&pm).unwrap().params(&net, "wskp", &[]).unwrap();
    for i in 0..net.convs.len() {
        let c = &net.convs[i];
        let n = c.spec.cout * c.cin * 25;
        let (mut a, mut b) = (vec![0.0; n], vec![0.0; n]);
        net.merge(&params, i, &mut a);
        net.merge(&merged, i, &mut b);
        for (x, y) in a.iter().zip(&b) {
            assert!((x - y).abs() <= 1e-6, "layer {i}: merged weights {x} vs {y}");
        }
    }
}

/// A RepVGG block's three convolutions plus the identity, summed, equal the
/// one merged 5x5 convolution that runs in training and inference.
#[test]
fn repvgg_branches_sum_to_the_merged_convolution() {
    let desc = NetDesc {
        cin: 6,
        layers: vec![Layer::Conv(Conv { k: 5, cout: 6, act: Activation::Identity, repvgg: true, bias: false })],
    };
    let net = Net::new(desc).unwrap();
    let params = net.init(9);
    let (w, h) = (23, 17);
    let x = Img::random(6, w, h, -1.0, 1.0, 3);
    let run = |k: usize, weights: &[f32]| {
        let layer = Conv2d { k, cin: 6, cout: 6, weights, bias: None, act: Activation::Identity, weight_frac: 0 };
        let mut out = Img::zeros(6, w, h);
        let mut s = vec![0.0; conv::conv2d_scratch_len::<F32>(k, 6, 6, w)];
        conv::conv2d::<F32>(Isa::Scalar, &layer, &x.view(), &mut out.view_mut(), 0, &mut s).unwrap();
        out.data
    };
    let c = &net.convs[0];
    let (n5, n3) = (36 * 25, 36 * 9);
    let b5 = run(5, &params[c.offset..c.offset + n5]);
    let b3 = run(3, &params[c.offset + n5..c.offset + n5 + n3]);
    let b1 = run(1, &params[c.offset + n5 + n3..c.offset + n5 + n3 + 36]);
    let mut merged = vec![0.0; n5];
    net.merge(&params, 0, &mut merged);
    let m = run(5, &merged);
    for i in 0..m.len() {
        let sum = b5[i] + b3[i] + b1[i] + x.data[i];
        assert!((sum - m[i]).abs() <= 1e-5 * (1.0 + sum.abs()), "element {i}: branches {sum} vs merged {}", m[i]);
    }
}

fn expect_err(bytes: Vec<u8>, want: &str) {
    let net = wskp::net(3).unwrap();
    let path = tmp("bad.safetensors");
    std::fs::write(&path, &bytes).unwrap();
    let e = File::read(&path).and_then(|f| f.params(&net, "wskp", &[])).unwrap_err().to_string();
    assert!(e.contains(want), "expected '{want}' in: {e}");
    assert!(e.contains("bad.safetensors"), "the error names the file: {e}");
}

fn file_with(edit: impl FnOnce(&mut Vec<(String, Vec<usize>, Vec<f32>)>), meta: &[(&str, String)]) -> Vec<u8> {
    let net = wskp::net(3).unwrap();
    let mut t = mcdenoise::nn::weights::param_tensors(&net, &net.init(1), Form::Branches);
    edit(&mut t);
    let tensors: Vec<Tensor<'_>> =
        t.iter().map(|(n, s, d)| Tensor { name: n.clone(), shape: s.clone(), data: d }).collect();
    let path = tmp("edit.safetensors");
    save(&path, &tensors, meta).unwrap();
    std::fs::read(&path).unwrap()
}

fn meta() -> Vec<(&'static str, String)> {
    vec![
        ("format", "mcdenoise-wskp".into()),
        ("version", "1".into()),
        ("form", "branches".into()),
        ("layers", "3".into()),
    ]
}

#[test]
fn bad_weight_files_name_the_file_and_the_tensor() {
    expect_err(b"not a safetensors file at all".to_vec(), "not a safetensors file");
    let good = file_with(|_| {}, &meta());
    expect_err(good[..good.len() / 2].to_vec(), "not a safetensors file");
    expect_err(
        file_with(|t| t.retain(|x| x.0 != "layers.1.conv3.weight"), &meta()),
        "tensor layers.1.conv3.weight missing",
    );
    expect_err(
        file_with(
            |t| {
                let e = t.iter_mut().find(|x| x.0 == "layers.0.conv5.weight").unwrap();
                e.1 = vec![14, 10, 25];
            },
            &meta(),
        ),
        "tensor layers.0.conv5.weight has shape [14, 10, 25], expected [14, 10, 5, 5]",
    );
    expect_err(
        file_with(
            |t| {
                let e = t.iter_mut().find(|x| x.0 == "layers.2.conv1.weight").unwrap();
                e.2[3] = f32::NAN;
            },
            &meta(),
        ),
        "tensor layers.2.conv1.weight holds a non-finite value",
    );
    expect_err(
        file_with(|t| t.push(("extra".into(), vec![1], vec![0.0])), &meta()),
        "tensor extra is not part of this network",
    );
    let mut other = meta();
    other[0].1 = "mcdenoise-afn".into();
    expect_err(file_with(|_| {}, &other), "metadata format is 'mcdenoise-afn', expected 'mcdenoise-wskp'");
    // A 6-layer file for the 3-layer network: the first missing tensor named.
    let net6 = wskp::net(6).unwrap();
    let path = tmp("six.safetensors");
    save_params(
        &path,
        &net6,
        &net6.init(1),
        Form::Branches,
        "wskp",
        &[("layers", "6".into()), ("transform", mcdenoise::methods::features::TRANSFORM.into())],
    )
    .unwrap();
    expect_err(
        std::fs::read(&path).unwrap(),
        "tensor layers.2.conv5.weight has shape [14, 14, 5, 5], expected [12, 14, 5, 5]",
    );
}

/// The PyTorch peer (tools/torch_wskp.py, `fixture`) computed the network's
/// output and the fused filter's in float64 for weights and one 17x13 frame
/// (tests/fixtures/wskp_torch/): ours, in f32 on every ISA, from the
/// branches file and from the merged file, agree.
#[test]
fn pytorch_forward_matches_ours() {
    use mcdenoise::methods::{context, Settings};
    use mcdenoise::nn::infer::Inference;
    use mcdenoise::runtime::precision::Planes;
    use mcdenoise_core::softmax::{self, FusedInputs, WindowPath};
    use mcdenoise_core::{View, ViewMut};
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/wskp_torch");
    let case = File::read(&dir.join("case.safetensors")).unwrap();
    let (w, h) = (17, 13);
    let x = case.tensor("x", &[10, h, w]).unwrap();
    let c = case.tensor("c", &[3, h, w]).unwrap();
    let alb = case.tensor("albedo", &[3, h, w]).unwrap();
    for layers in [3, 6] {
        let want_logits = case.tensor(&format!("logits{layers}"), &[12, h, w]).unwrap();
        let want_out = case.tensor(&format!("out{layers}"), &[3, h, w]).unwrap();
        let net = wskp::net(layers).unwrap();
        for file in [format!("wskp{layers}.safetensors"), format!("wskp{layers}_merged.safetensors")] {
            let params = File::read(&dir.join(&file)).unwrap().params(&net, "wskp", &[]).unwrap();
            for isa in mcdenoise_tests::isas_under_test() {
                let mut ctx = context(&Settings { isa, threads: 2, ..Settings::default() }).unwrap();
                let mut inf = Inference::<F32>::new(&net, &params, None, None).unwrap();
                let logits = inf.run(&mut ctx, Planes::from_vec(10, w, h, x.clone())).unwrap().data.to_vec();
                let peak = want_logits.iter().fold(0.0f32, |m, v| m.max(v.abs()));
                for (i, (a, b)) in logits.iter().zip(&want_logits).enumerate() {
                    assert!((a - b).abs() <= 2e-5 * peak, "{file} {isa:?}: logit {i} is {a}, PyTorch {b}");
                }
                let lv = View::new(&logits, 12, w, h).unwrap();
                let inp = FusedInputs {
                    sizes: &wskp::SIZES,
                    importance: lv.channels_range(0, 6).unwrap(),
                    fusion: Some(lv.channels_range(6, 6).unwrap()),
                    albedo: Some(View::new(&alb, 3, w, h).unwrap()),
                    radiance: View::new(&c, 3, w, h).unwrap(),
                };
                let mut out = vec![0.0f32; 3 * w * h];
                let mut s = vec![0.0; softmax::fused_scratch_len::<F32>(WindowPath::Separable, &wskp::SIZES, 3, w)];
                softmax::fused_filter::<F32>(
                    isa,
                    WindowPath::Separable,
                    &inp,
                    &mut ViewMut::new(&mut out, 3, w, h).unwrap(),
                    0,
                    &mut s,
                )
                .unwrap();
                for (i, (a, b)) in out.iter().zip(&want_out).enumerate() {
                    assert!((a - b).abs() <= 1e-4 * (1.0 + b.abs()), "{file} {isa:?}: output {i} is {a}, PyTorch {b}");
                }
            }
        }
    }
}

/// Window sizes: parsed from the CLI's form, written as the weights' `sizes`
/// metadata and read back from it (absent: the paper's six); a file for
/// one size does not load as the six-size network (its last layer has one
/// output plane, named in the error), and bad metadata is refused by name.
#[test]
fn window_sizes_round_trip_through_the_weights_file() {
    use mcdenoise::methods::wskp::Sizes;
    assert_eq!(Sizes::parse("3,5,7,9,11,13").unwrap(), Sizes::ALL);
    assert_eq!(Sizes::parse("13, 3").unwrap().name(), "3,13");
    let one = Sizes::parse("7").unwrap();
    assert_eq!((one.count(), one.outputs(), one.array()[0]), (1, 1, 7));
    assert_eq!(Sizes::ALL.outputs(), 12);
    // Size 1, the identity: one logit more, not a window.
    assert_eq!(Sizes::parse("13,1,3,5,7,9,11").unwrap(), Sizes::ALL_AND_INPUT);
    assert_eq!(Sizes::ALL_AND_INPUT.name(), "1,3,5,7,9,11,13");
    assert_eq!(
        (Sizes::ALL_AND_INPUT.count(), Sizes::ALL_AND_INPUT.outputs(), Sizes::ALL_AND_INPUT.keep()),
        (6, 13, true)
    );
    assert!(!Sizes::ALL.keep());
    let k1 = Sizes::parse("1,7").unwrap();
    assert_eq!((k1.count(), k1.outputs(), k1.array()[0], k1.name()), (1, 2, 7, "1,7".to_string()));
    for (bad, why) in [
        ("4", "got 4"),
        ("7,7", "twice"),
        ("", "expected sizes"),
        ("15", "got 15"),
        ("x", "expected"),
        ("1", "at least one window size"),
        ("1,1,3", "twice"),
    ] {
        let e = Sizes::parse(bad).unwrap_err();
        assert!(e.contains(why), "'{bad}': {e}");
    }
    let net = wskp::net_for(3, one).unwrap();
    let path = tmp("k7.safetensors");
    let meta = [
        ("layers", "3".to_string()),
        ("sizes", one.name()),
        ("transform", mcdenoise::methods::features::TRANSFORM.into()),
    ];
    save_params(&path, &net, &net.init(2), Form::Branches, "wskp", &meta).unwrap();
    let f = File::read(&path).unwrap();
    assert_eq!(Sizes::of_file(&f).unwrap(), one);
    assert_eq!(f.params(&net, "wskp", &[]).unwrap().len(), net.params);
    let e = f.params(&wskp::net(3).unwrap(), "wskp", &[]).unwrap_err().to_string();
    assert!(e.contains("layers.2.conv5.weight has shape [1, 14, 5, 5], expected [12, 14, 5, 5]"), "{e}");
    // No sizes metadata: the six.
    let p6 = tmp("six3.safetensors");
    let n3 = wskp::net(3).unwrap();
    save_params(
        &p6,
        &n3,
        &n3.init(1),
        Form::Branches,
        "wskp",
        &[("layers", "3".into()), ("transform", mcdenoise::methods::features::TRANSFORM.into())],
    )
    .unwrap();
    assert_eq!(Sizes::of_file(&File::read(&p6).unwrap()).unwrap(), Sizes::ALL);
    let pb = tmp("badsizes.safetensors");
    save_params(
        &pb,
        &net,
        &net.init(2),
        Form::Branches,
        "wskp",
        &[("layers", "3".into()), ("sizes", "8".into()), ("transform", mcdenoise::methods::features::TRANSFORM.into())],
    )
    .unwrap();
    let e = Sizes::of_file(&File::read(&pb).unwrap()).unwrap_err().to_string();
    assert!(e.contains("sizes metadata") && e.contains("got 8"), "{e}");
}
