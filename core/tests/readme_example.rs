//! The README's "Embedding the core" code is the `fixed_buffers` example's
//! `denoise_tile`, word for word, so what the README shows is what
//! `cargo test` compiles and CI runs.

#[test]
fn readme_shows_the_compiled_example() {
    let root = concat!(env!("CARGO_MANIFEST_DIR"), "/..");
    let readme = std::fs::read_to_string(format!("{root}/README.md")).unwrap();
    let example = std::fs::read_to_string(format!("{root}/core/examples/fixed_buffers.rs")).unwrap();
    let section = readme.split("## Embedding the core").nth(1).expect("the README has the section");
    let code = section.split("```rust\n").nth(1).and_then(|s| s.split("```").next()).expect("a rust block");
    assert!(code.contains("fn denoise_tile"), "{code}");
    assert!(example.contains(code), "README's block is not in core/examples/fixed_buffers.rs:\n{code}");
}
