//! Arbitrary text as a config file: parsing never panics, and a config that parses serializes
//! to TOML that parses back to the same serialization (what `infraloc simulate` relies on when it
//! writes a scene's infraloc.toml).
#![no_main]

use infraloc::config::Config;
use libfuzzer_sys::fuzz_target;
use std::path::Path;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(cfg) = Config::parse(text, Path::new("fuzz.toml")) {
        let _ = cfg.validate(Path::new("fuzz.toml"));
        let _ = cfg.check();
        if let Ok(out) = toml::to_string(&cfg) {
            let back = Config::parse(&out, Path::new("fuzz.toml")).expect("re-parse");
            assert_eq!(toml::to_string(&back).unwrap(), out);
        }
    }
});
