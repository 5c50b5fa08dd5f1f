//! Lets the `ground` binary find libtorch at run time without LD_LIBRARY_PATH: with the `learn`
//! feature, the libtorch folder tch linked against (LIBTORCH, set in .cargo/config.toml) goes
//! into the rpath.
fn main() {
    println!("cargo:rerun-if-env-changed=LIBTORCH");
    if std::env::var_os("CARGO_FEATURE_LEARN").is_none() {
        return;
    }
    if let Ok(dir) = std::env::var("LIBTORCH") {
        let lib = std::path::Path::new(&dir).join("lib");
        let lib = lib.canonicalize().unwrap_or(lib);
        println!("cargo:rustc-link-arg=-Wl,-rpath,{}", lib.display());
    }
}
