//! The checked-in header is what cbindgen generates from the sources now, so C callers never
//! compile against a stale interface. `LOWTHRUST_BLESS_HEADER=1` rewrites it instead.

use std::path::Path;

#[test]
fn the_checked_in_header_is_what_cbindgen_generates() {
    let crate_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let config = cbindgen::Config::from_file(crate_dir.join("cbindgen.toml")).expect("cbindgen.toml");
    let bindings = cbindgen::Builder::new()
        .with_crate(crate_dir)
        .with_config(config)
        .generate()
        .expect("cbindgen generates the header");
    let mut generated = Vec::new();
    bindings.write(&mut generated);
    let path = crate_dir.join("include/lowthrust.h");
    if std::env::var_os("LOWTHRUST_BLESS_HEADER").is_some() {
        std::fs::write(&path, &generated).expect("write include/lowthrust.h");
        return;
    }
    let checked_in = String::from_utf8_lossy(&std::fs::read(&path).unwrap_or_default()).into_owned();
    let generated = String::from_utf8_lossy(&generated).into_owned();
    if checked_in != generated {
        let first_difference = checked_in
            .lines()
            .map(Some)
            .chain(std::iter::repeat(None))
            .zip(generated.lines().map(Some).chain(std::iter::repeat(None)))
            .take_while(|pair| *pair != (None, None))
            .enumerate()
            .find(|(_, (old, new))| old != new);
        let (line, (old, new)) = first_difference.unwrap_or((0, (None, None)));
        panic!(
            "{} differs from what cbindgen generates, first at line {}:\n  checked in: {}\n  generated:  {}\n\
             rewrite it with LOWTHRUST_BLESS_HEADER=1 cargo test -p lowthrust-onboard-c --test header",
            path.display(),
            line + 1,
            old.unwrap_or("(end of file)"),
            new.unwrap_or("(end of file)")
        );
    }
}
