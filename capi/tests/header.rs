//! `include/pinc.h` is what cbindgen generates from `capi/src` today. Run with
//! `PINC_BLESS=1` to rewrite it after changing the C ABI.

use std::path::Path;

#[test]
fn the_committed_header_equals_a_fresh_generation() {
    let crate_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let config = cbindgen::Config::from_file(crate_dir.join("cbindgen.toml")).expect("cbindgen.toml");
    let mut fresh = Vec::new();
    cbindgen::Builder::new()
        .with_crate(crate_dir)
        .with_config(config)
        .generate()
        .expect("cbindgen generates the header")
        .write(&mut fresh);
    let path = crate_dir.join("../include/pinc.h");
    if std::env::var_os("PINC_BLESS").is_some() {
        std::fs::write(&path, &fresh).expect("write include/pinc.h");
    }
    let committed = std::fs::read(&path).unwrap_or_default();
    assert!(
        committed == fresh,
        "include/pinc.h differs from what cbindgen generates from capi/src; regenerate it with \
         `PINC_BLESS=1 cargo test -p pinc-capi --test header` and commit it"
    );
}
