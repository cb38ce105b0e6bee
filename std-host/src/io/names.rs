//! Which channels of an OpenEXR file are which buffer: the input contract's
//! names, the names other renderers write (Mitsuba's AOVs, pbrt-v4's
//! G-buffer film, Blender's passes), a layer prefix (`ViewLayer.`; Blender's
//! multilayer files, or any `--layer`), and channels across the parts of a
//! multi-part file.
//!
//! Blender (Cycles) writes `<view layer>.<pass>.<channel>`: `Combined.R/G/B`
//! (the noisy image), `Denoising Albedo.R/G/B` (or `Diffuse Color`,
//! `DiffCol` before Blender 5), `Normal.X/Y/Z` (world space; `Denoising
//! Normal` is in camera space and is not used), `Position.X/Y/Z` (world
//! space), `Depth.Z` (distance along the view axis; 1e10 where nothing is
//! hit, read as 0) and `Vector.X/Y/Z/W` (X, Y: the motion to the previous
//! frame in pixels with y pointing up, read as `motion = (X, -Y)`; Z, W: to
//! the next frame, not used). These conventions are in Cycles' kernel
//! (`kernel/geom/primitive.h`, `kernel/film/data_passes.h`).

use crate::error::{HostError, Result};
use crate::io::frame::Buffer;

/// How a matched channel set's values become the buffer's.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Convert {
    /// As they are.
    Plain,
    /// Blender's `Vector`: the second component negated (y up).
    FlipY,
    /// Blender's `Depth`: values of 1e9 and more (its 1e10 background) are 0.
    FarIsZero,
}

/// One accepted set of channel names for a buffer, and how to read it.
#[derive(Clone, Copy, Debug)]
pub struct Alias {
    /// The names, one per plane.
    pub names: &'static [&'static str],
    /// The conversion.
    pub convert: Convert,
    /// The renderer whose convention this is (for `inspect`).
    pub from: &'static str,
}

const fn a(names: &'static [&'static str], from: &'static str) -> Alias {
    Alias { names, convert: Convert::Plain, from }
}

/// The accepted sets of a buffer, the contract's names first.
pub fn aliases(b: Buffer) -> &'static [Alias] {
    const COLOR: &[Alias] =
        &[a(&["R", "G", "B"], "the contract"), a(&["Combined.R", "Combined.G", "Combined.B"], "Blender")];
    const COLOR_B: &[Alias] = &[a(&["B.R", "B.G", "B.B"], "the contract")];
    const ALBEDO: &[Alias] = &[
        a(&["albedo.R", "albedo.G", "albedo.B"], "the contract, Mitsuba"),
        a(&["Albedo.R", "Albedo.G", "Albedo.B"], "pbrt-v4"),
        a(&["Denoising Albedo.R", "Denoising Albedo.G", "Denoising Albedo.B"], "Blender"),
        a(&["Diffuse Color.R", "Diffuse Color.G", "Diffuse Color.B"], "Blender"),
        a(&["DiffCol.R", "DiffCol.G", "DiffCol.B"], "Blender before 5.0"),
    ];
    const NORMAL: &[Alias] = &[
        a(&["normal.X", "normal.Y", "normal.Z"], "the contract"),
        a(&["normal.R", "normal.G", "normal.B"], "the contract"),
        a(&["sh_normal.X", "sh_normal.Y", "sh_normal.Z"], "Mitsuba"),
        a(&["nn.X", "nn.Y", "nn.Z"], "Mitsuba"),
        a(&["N.X", "N.Y", "N.Z"], "pbrt-v4"),
        a(&["Normal.X", "Normal.Y", "Normal.Z"], "Blender"),
    ];
    const DEPTH: &[Alias] = &[
        a(&["depth.Z"], "the contract"),
        a(&["Z"], "the contract"),
        a(&["depth.T"], "Mitsuba"),
        a(&["depth.Y"], "the contract"),
        a(&["depth.R"], "the contract"),
        a(&["dd.T"], "Mitsuba"),
        a(&["dd.Y"], "Mitsuba"),
        Alias { names: &["Depth.Z"], convert: Convert::FarIsZero, from: "Blender" },
    ];
    const POSITION: &[Alias] = &[
        a(&["position.X", "position.Y", "position.Z"], "the contract"),
        a(&["position.R", "position.G", "position.B"], "the contract"),
        a(&["pp.X", "pp.Y", "pp.Z"], "Mitsuba"),
        a(&["P.X", "P.Y", "P.Z"], "pbrt-v4"),
        a(&["Position.X", "Position.Y", "Position.Z"], "Blender"),
    ];
    const MOTION: &[Alias] = &[
        a(&["motion.X", "motion.Y"], "the contract"),
        a(&["motion.R", "motion.G"], "the contract"),
        a(&["mv.X", "mv.Y"], "the contract"),
        Alias { names: &["Vector.X", "Vector.Y"], convert: Convert::FlipY, from: "Blender" },
    ];
    match b {
        Buffer::Color => COLOR,
        Buffer::ColorB => COLOR_B,
        Buffer::Albedo => ALBEDO,
        Buffer::Normal => NORMAL,
        Buffer::Depth => DEPTH,
        Buffer::Position => POSITION,
        Buffer::Motion => MOTION,
    }
}

/// Where a buffer's planes come from: one `(part, channel index)` per plane.
#[derive(Clone, Debug, PartialEq)]
pub struct Found {
    /// Part and channel index of each plane.
    pub channels: Vec<(usize, usize)>,
    /// The full channel names, one per plane.
    pub names: Vec<String>,
    /// How to read the values.
    pub convert: Convert,
    /// Whose convention the names follow.
    pub from: &'static str,
    /// Other parts that have channels of these names (not read; `--part`
    /// chooses).
    pub also_in: Vec<String>,
}

/// What the user chose where a file is ambiguous.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Selection {
    /// `--part NAME`: the part whose channels win where names clash (by
    /// default the first part that has them).
    pub part: Option<String>,
    /// `--layer NAME`: the layer prefix (`NAME.`) of every buffer's channels.
    pub layer: Option<String>,
}

/// A part's name and channel names, as the resolver sees them.
#[derive(Clone, Debug)]
pub struct PartChannels {
    /// The part's name (`name` attribute), if it has one.
    pub name: Option<String>,
    /// Its channel names, in the file's order.
    pub channels: Vec<String>,
}

/// The buffers found in a file: for each, where its planes come from, and
/// the layer prefix used.
#[derive(Clone, Debug)]
pub struct Resolved {
    /// Per buffer ([`Buffer::ALL`] order).
    pub sets: [Option<Found>; 7],
    /// The layer prefix (without its dot) every buffer was found under, if any.
    pub layer: Option<String>,
}

/// Every name a channel answers to: its own, and `<part name>.<name>` in a
/// named part (a part `albedo` holding `R,G,B` is read as `albedo.R` ...).
fn full_names(p: &PartChannels, c: &str) -> Vec<String> {
    let mut v = vec![c.to_string()];
    if let Some(n) = &p.name {
        v.push(format!("{n}.{c}"));
    }
    v
}

/// The `(part, channel)` answering to `name`; with several, the one in the
/// `--part` part, else the first (part 0 is a file's main image by
/// OpenEXR's convention); `clashes` collects the other parts' names.
fn lookup(parts: &[PartChannels], sel: &Selection, name: &str, clashes: &mut Vec<String>) -> Option<(usize, usize)> {
    let mut hits = Vec::new();
    for (pi, p) in parts.iter().enumerate() {
        for (ci, c) in p.channels.iter().enumerate() {
            if full_names(p, c).iter().any(|n| n == name) {
                hits.push((pi, ci));
            }
        }
    }
    let chosen = sel
        .part
        .as_ref()
        .and_then(|want| hits.iter().copied().find(|(pi, _)| parts[*pi].name.as_deref() == Some(want.as_str())))
        .or_else(|| hits.first().copied())?;
    for &(pi, _) in hits.iter().filter(|h| **h != chosen) {
        let n = parts[pi].name.clone().map_or(format!("part {pi}"), |n| format!("'{n}'"));
        if !clashes.contains(&n) {
            clashes.push(n);
        }
    }
    Some(chosen)
}

/// The layer prefixes `L` under which Blender's colour `L.Combined.R/G/B`
/// is complete (other layered files name their layer with `--layer`).
fn colour_layers(parts: &[PartChannels]) -> Vec<String> {
    let names: Vec<String> = parts.iter().flat_map(|p| p.channels.iter().flat_map(move |c| full_names(p, c))).collect();
    let mut layers: Vec<String> = Vec::new();
    for n in &names {
        if let Some(layer) = n.strip_suffix(".Combined.R") {
            let all = ["Combined.G", "Combined.B"].iter().all(|x| names.contains(&format!("{layer}.{x}")));
            if all && !layers.iter().any(|l| l == layer) {
                layers.push(layer.to_string());
            }
        }
    }
    layers
}

/// Finds every buffer in a file's parts. The layer: `--layer`, else none
/// when the colour is found without a prefix, else the one Blender view
/// layer with a `Combined` pass (Blender's `Composite` layer, the
/// compositor's output, counts only when it is the only one); several
/// layers without `--layer` are an error listing them. A set partly present is an error naming what is
/// missing.
pub fn resolve(parts: &[PartChannels], sel: &Selection, file: &std::path::Path) -> Result<Resolved> {
    let layer = match &sel.layer {
        Some(l) => Some(l.clone()),
        None => {
            let bare = aliases(Buffer::Color)
                .iter()
                .any(|al| al.names.iter().all(|n| lookup(parts, sel, n, &mut Vec::new()).is_some()));
            if bare {
                None
            } else {
                let mut layers = colour_layers(parts);
                if layers.len() > 1 {
                    layers.retain(|l| l != "Composite");
                }
                match layers.len() {
                    0 => None,
                    1 => layers.pop(),
                    _ => {
                        return Err(HostError::bad(
                            file,
                            format!("has the layers {}; choose one with --layer NAME", layers.join(", ")),
                        ))
                    }
                }
            }
        }
    };
    let prefix = layer.as_ref().map(|l| format!("{l}.")).unwrap_or_default();
    let mut sets: [Option<Found>; 7] = Default::default();
    for b in Buffer::ALL {
        for al in aliases(b) {
            let names: Vec<String> = al.names.iter().map(|n| format!("{prefix}{n}")).collect();
            let mut also_in = Vec::new();
            let hits: Vec<Option<(usize, usize)>> = names.iter().map(|n| lookup(parts, sel, n, &mut also_in)).collect();
            let present = hits.iter().filter(|h| h.is_some()).count();
            if present == names.len() {
                sets[b.index()] = Some(Found {
                    channels: hits.into_iter().map(|h| h.expect("all present")).collect(),
                    names,
                    convert: al.convert,
                    from: al.from,
                    also_in,
                });
                break;
            }
            if present > 0 && names.len() > 1 {
                let (have, miss): (Vec<_>, Vec<_>) = names.iter().zip(&hits).partition(|(_, h)| h.is_some());
                let have: Vec<&str> = have.iter().map(|(n, _)| n.as_str()).collect();
                let miss: Vec<&str> = miss.iter().map(|(n, _)| n.as_str()).collect();
                return Err(HostError::bad(
                    file,
                    format!("{} channels are incomplete: has {} but not {}", b.name(), have.join(","), miss.join(",")),
                ));
            }
        }
    }
    if sets[Buffer::Color.index()].is_none() {
        let wanted = match &layer {
            Some(l) => format!("{l}.R,{l}.G,{l}.B or {l}.Combined.R/G/B"),
            None => "R,G,B".to_string(),
        };
        return Err(HostError::MissingChannel {
            path: file.to_path_buf(),
            buffer: "colour",
            wanted,
            needed_by: "every method".into(),
        });
    }
    Ok(Resolved { sets, layer })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn part(name: Option<&str>, ch: &[&str]) -> PartChannels {
        PartChannels { name: name.map(String::from), channels: ch.iter().map(|s| s.to_string()).collect() }
    }

    #[test]
    fn blender_single_layer_is_detected() {
        let p = [part(
            None,
            &[
                "ViewLayer.Combined.R",
                "ViewLayer.Combined.G",
                "ViewLayer.Combined.B",
                "ViewLayer.Combined.A",
                "ViewLayer.Denoising Albedo.R",
                "ViewLayer.Denoising Albedo.G",
                "ViewLayer.Denoising Albedo.B",
                "ViewLayer.Normal.X",
                "ViewLayer.Normal.Y",
                "ViewLayer.Normal.Z",
                "ViewLayer.Vector.X",
                "ViewLayer.Vector.Y",
                "ViewLayer.Vector.Z",
                "ViewLayer.Vector.W",
                "ViewLayer.Depth.Z",
            ],
        )];
        let r = resolve(&p, &Selection::default(), Path::new("f.exr")).unwrap();
        assert_eq!(r.layer.as_deref(), Some("ViewLayer"));
        assert_eq!(r.sets[Buffer::Color.index()].as_ref().unwrap().channels, vec![(0, 0), (0, 1), (0, 2)]);
        assert_eq!(r.sets[Buffer::Albedo.index()].as_ref().unwrap().channels, vec![(0, 4), (0, 5), (0, 6)]);
        assert_eq!(r.sets[Buffer::Motion.index()].as_ref().unwrap().convert, Convert::FlipY);
        assert_eq!(r.sets[Buffer::Depth.index()].as_ref().unwrap().convert, Convert::FarIsZero);
        assert!(r.sets[Buffer::Position.index()].is_none());
    }

    #[test]
    fn two_layers_need_a_choice() {
        let p = [part(
            None,
            &["A.Combined.R", "A.Combined.G", "A.Combined.B", "B.Combined.R", "B.Combined.G", "B.Combined.B"],
        )];
        let e = resolve(&p, &Selection::default(), Path::new("f.exr")).unwrap_err().to_string();
        assert!(e.contains("--layer") && e.contains('A') && e.contains('B'), "{e}");
        let sel = Selection { layer: Some("B".into()), ..Selection::default() };
        let r = resolve(&p, &sel, Path::new("f.exr")).unwrap();
        assert_eq!(r.sets[0].as_ref().unwrap().channels, vec![(0, 3), (0, 4), (0, 5)]);
    }

    #[test]
    fn parts_are_searched_and_clashes_named() {
        let p = [part(Some("rgba"), &["R", "G", "B"]), part(Some("aovs"), &["albedo.R", "albedo.G", "albedo.B"])];
        let r = resolve(&p, &Selection::default(), Path::new("f.exr")).unwrap();
        assert_eq!(r.sets[Buffer::Albedo.index()].as_ref().unwrap().channels, vec![(1, 0), (1, 1), (1, 2)]);
        // A part named like a buffer: its R,G,B answer to albedo.R/G/B;
        // the bare R,G,B are the first part's unless --part says.
        let p = [part(Some("beauty"), &["R", "G", "B"]), part(Some("albedo"), &["R", "G", "B"])];
        let r = resolve(&p, &Selection::default(), Path::new("f.exr")).unwrap();
        let c = r.sets[0].as_ref().unwrap();
        assert_eq!(c.channels, vec![(0, 0), (0, 1), (0, 2)]);
        assert_eq!(c.also_in, vec!["'albedo'".to_string()]);
        assert_eq!(r.sets[Buffer::Albedo.index()].as_ref().unwrap().channels, vec![(1, 0), (1, 1), (1, 2)]);
        let sel = Selection { part: Some("albedo".into()), ..Selection::default() };
        let r = resolve(&p, &sel, Path::new("f.exr")).unwrap();
        assert_eq!(r.sets[0].as_ref().unwrap().channels, vec![(1, 0), (1, 1), (1, 2)]);
    }

    #[test]
    fn incomplete_sets_are_errors() {
        let p = [part(None, &["R", "G", "B", "albedo.R", "albedo.G"])];
        let e = resolve(&p, &Selection::default(), Path::new("f.exr")).unwrap_err().to_string();
        assert!(e.contains("albedo.B"), "{e}");
    }
}
