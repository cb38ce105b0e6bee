//! EXR files as production pipelines write them: the fixtures in
//! tests/fixtures/layouts were written by the OpenEXR library itself (its
//! PyPI package, tools/make_exr_fixtures.py), each holding the same two
//! frames in another layout. Every layout must denoise to exactly the
//! pixels of the plain layout, and the output must keep the input's
//! windows, attributes, names and (with --keep-channels) every channel.

mod common;

use std::path::{Path, PathBuf};

use common::*;
use mcdenoise::io::frame::{Frame, Limits};

fn layouts() -> PathBuf {
    fixtures().join("layouts")
}

/// Runs `denoise` and returns the output directory.
fn denoise(dir: &Path, input: &str, extra: &[&str], method: &[&str]) -> PathBuf {
    let out = dir.join(input.replace('/', "_") + &extra.join("_").replace('-', ""));
    let mut c = bin();
    c.args(["denoise", "--quiet", "--threads", "2"]).args(method).args(extra);
    c.arg(layouts().join(input)).arg("-o").arg(&out);
    let r = c.output().unwrap();
    assert!(r.status.success(), "{input} {extra:?}: {}", String::from_utf8_lossy(&r.stderr));
    out
}

/// The header of `path`'s parts, read by the exr crate.
fn headers(path: &Path) -> Vec<exr::meta::header::Header> {
    exr::meta::MetaData::read_from_file(path, false).unwrap().headers.to_vec()
}

/// The colour planes of an output (under whatever names it has).
fn colour(path: &Path, layer: Option<&str>) -> Vec<f32> {
    let mut opts = mcdenoise::io::frame::ReadOptions::default();
    opts.selection.layer = layer.map(String::from);
    let f = Frame::load_with(path, &Limits::default(), &opts).unwrap();
    f.get(mcdenoise::Buffer::Color).unwrap().to_vec()
}

const METHODS: [&[&str]; 3] = [&["--method", "atrous"], &["--method", "wskp", "--layers", "3"], &["--method", "afn"]];

#[test]
fn every_layout_denoises_to_the_plain_layout_pixels() {
    let t = tempfile::tempdir().unwrap();
    for method in METHODS {
        let plain = denoise(t.path(), "plain", &[], method);
        let cases: [(&str, &[&str], Option<&str>); 6] = [
            ("multipart", &[], None),
            ("clash", &["--part", "beauty"], None),
            ("blender", &[], Some("ViewLayer")),
            ("window", &[], None),
            ("tiled_mip", &[], None),
            ("separate/frames", &["--albedo", "ALBEDO", "--normal", "NORMAL"], None),
        ];
        for (input, extra, layer) in cases {
            let extra: Vec<String> = extra
                .iter()
                .map(|a| match *a {
                    "ALBEDO" => layouts().join("separate/albedo").display().to_string(),
                    "NORMAL" => layouts().join("separate/normal").display().to_string(),
                    other => other.to_string(),
                })
                .collect();
            let extra: Vec<&str> = extra.iter().map(|s| s.as_str()).collect();
            let out = denoise(t.path(), input, &extra, method);
            for frame in ["frame_0000.exr", "frame_0001.exr"] {
                let a = colour(&plain.join(frame), None);
                let b = colour(&out.join(frame), layer);
                assert!(a == b, "{method:?} {input} {frame}: pixels differ from the plain layout's");
            }
        }
    }
}

#[test]
fn the_output_keeps_windows_attributes_and_line_order() {
    let t = tempfile::tempdir().unwrap();
    let out = denoise(t.path(), "window", &[], &["--method", "atrous"]);
    let (i, o) = (headers(&layouts().join("window/frame_0000.exr")), headers(&out.join("frame_0000.exr")));
    let (i, o) = (&i[0], &o[0]);
    assert_eq!(o.own_attributes.layer_position, i.own_attributes.layer_position);
    assert_eq!(o.own_attributes.layer_position, exr::math::Vec2(10, 10));
    assert_eq!(o.layer_size, i.layer_size);
    assert_eq!(o.shared_attributes.display_window, i.shared_attributes.display_window);
    assert_eq!(o.shared_attributes.pixel_aspect, 1.25);
    assert_eq!(o.line_order, exr::meta::attribute::LineOrder::Decreasing);
    assert_eq!(o.shared_attributes.chromaticities, i.shared_attributes.chromaticities);
    assert!(i.own_attributes.world_to_camera.is_some());
    assert_eq!(o.own_attributes.world_to_camera, i.own_attributes.world_to_camera);
    let k = exr::meta::attribute::Text::from("renderer");
    let got = o.own_attributes.other.get(&k).or(o.shared_attributes.other.get(&k));
    let want = i.own_attributes.other.get(&k).or(i.shared_attributes.other.get(&k));
    assert!(want.is_some() && got == want, "attribute renderer: {got:?} against {want:?}");
    // The colour under the input's names and pixel type (f16 here).
    let names: Vec<String> = o.channels.list.iter().map(|c| c.name.to_string()).collect();
    assert_eq!(names, ["B", "G", "R"]);
    assert!(o.channels.list.iter().all(|c| c.sample_type == exr::meta::attribute::SampleType::F16));
}

#[test]
fn keep_channels_copies_every_other_channel_and_part() {
    let t = tempfile::tempdir().unwrap();
    let out = denoise(t.path(), "window", &["--keep-channels"], &["--method", "atrous"]);
    let inp = layouts().join("window/frame_0001.exr");
    let o = out.join("frame_0001.exr");
    let read_all = |p: &Path| {
        exr::prelude::read_all_flat_layers_from_file(p)
            .unwrap()
            .layer_data
            .into_iter()
            .next()
            .unwrap()
            .channel_data
            .list
    };
    let (a, b) = (read_all(&inp), read_all(&o));
    assert_eq!(a.len(), b.len(), "every channel is in the output");
    for (x, y) in a.iter().zip(&b) {
        assert_eq!(x.name, y.name);
        if !["R", "G", "B"].contains(&x.name.to_string().as_str()) {
            assert!(x.sample_data == y.sample_data, "{} copied unchanged (type and values)", x.name);
        }
    }
    let out = denoise(t.path(), "multipart", &["--keep-channels"], &["--method", "wskp", "--layers", "3"]);
    let parts = headers(&out.join("frame_0000.exr"));
    let names: Vec<String> =
        parts.iter().map(|h| h.own_attributes.layer_name.as_ref().map(|n| n.to_string()).unwrap_or_default()).collect();
    assert_eq!(names, ["rgba", "aovs"]);
    assert_eq!(parts[1].channels.list.len(), 12);
}

#[test]
fn where_parts_share_names_the_first_wins_and_inspect_says_so() {
    let t = tempfile::tempdir().unwrap();
    let a = denoise(t.path(), "clash", &[], &["--method", "atrous"]);
    let b = denoise(t.path(), "clash", &["--part", "beauty"], &["--method", "atrous"]);
    assert!(colour(&a.join("frame_0000.exr"), None) == colour(&b.join("frame_0000.exr"), None));
    let r = bin().arg("inspect").arg(layouts().join("clash/frame_0000.exr")).output().unwrap();
    let s = String::from_utf8_lossy(&r.stdout);
    assert!(s.contains("R [part 0]") && s.contains("also in 'albedo' (--part chooses)"), "{s}");
}

#[test]
fn inspect_names_what_the_loader_found() {
    let r = bin().arg("inspect").arg(layouts().join("blender/frame_0000.exr")).output().unwrap();
    assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    let s = String::from_utf8_lossy(&r.stdout);
    for want in [
        "layer: ViewLayer",
        "ViewLayer.Denoising Albedo.R [part 0]",
        "ViewLayer.Vector.Y [part 0]",
        "y negated",
        "Blender naming",
        "cross: cannot run",
        "wskp: stages temporal accumulation",
    ] {
        assert!(s.contains(want), "inspect says {want:?}:\n{s}");
    }
    let r = bin().arg("inspect").arg(layouts().join("multipart/frame_0000.exr")).output().unwrap();
    let s = String::from_utf8_lossy(&r.stdout);
    assert!(s.contains("part 1 'aovs'") && s.contains("albedo.R [part 1]"), "{s}");
}

#[test]
fn output_pixel_type_and_compression_are_options() {
    let t = tempfile::tempdir().unwrap();
    for (args, sample, compression) in [
        (&["--float"][..], exr::meta::attribute::SampleType::F32, exr::compression::Compression::ZIP16),
        (
            &["--half", "--compression", "piz"][..],
            exr::meta::attribute::SampleType::F16,
            exr::compression::Compression::PIZ,
        ),
        (
            &["--compression", "none"][..],
            exr::meta::attribute::SampleType::F16,
            exr::compression::Compression::Uncompressed,
        ),
        (
            &["--compression", "dwaa"][..],
            exr::meta::attribute::SampleType::F16,
            exr::compression::Compression::DWAA(None),
        ),
    ] {
        let out = denoise(t.path(), "plain", args, &["--method", "atrous"]);
        let h = &headers(&out.join("frame_0000.exr"))[0];
        assert!(h.channels.list.iter().all(|c| c.sample_type == sample), "{args:?}");
        assert_eq!(std::mem::discriminant(&h.compression), std::mem::discriminant(&compression), "{args:?}");
    }
}
