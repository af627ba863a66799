//! Thin binary: all behaviour lives in the library so tests and the daemon share it.
fn main() {
    std::process::exit(infraloc::cli::main());
}
