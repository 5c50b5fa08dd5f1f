//! Puts the linker script where cortex-m-rt's link.x finds it, and the weight blob named by
//! `LOWTHRUST_BLOB` into OUT_DIR for `include_bytes!` (the image embeds it in flash).
use std::path::PathBuf;
use std::{env, fs, process};

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    fs::write(out.join("memory.x"), include_bytes!("memory.x")).expect("write memory.x to OUT_DIR");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-env-changed=LOWTHRUST_BLOB");

    let Some(blob) = env::var_os("LOWTHRUST_BLOB") else {
        eprintln!(
            "error: LOWTHRUST_BLOB is not set: give the weight blob to embed, e.g.\n  \
             LOWTHRUST_BLOB=/path/transfer-int8.blob cargo build --release\n\
             (scripts/qemu-sil.sh does this; firmware_sim's random_blob writes test blobs)"
        );
        process::exit(1);
    };
    let blob = PathBuf::from(blob);
    println!("cargo:rerun-if-changed={}", blob.display());
    // Copied, not referenced, so the image depends on the bytes, not on where they were.
    if let Err(e) = fs::copy(&blob, out.join("policy.blob")) {
        eprintln!("error: cannot read LOWTHRUST_BLOB={}: {e}", blob.display());
        process::exit(1);
    }
}
